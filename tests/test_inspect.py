"""pipeline.inspect: a work directory's artifacts as lazy xarray Datasets."""

from __future__ import annotations

import dask.array as da
import numpy as np
import pytest
from helpers import PROJECT, small_scene_dict, write_scene

from pipeline import inspect
from pipeline.errors import PrtError
from pipeline.runner import run
from pipeline.scene import load_scene
from pipeline.schema import load_schema
from pipeline.stagefile import load_stagefile
from pipeline.store import Workdir, open_artifact


def test_an_artifact_opens_lazily_with_its_schema_dims_and_provenance(tmp_path):
    """The geometry of a small scene (segmented arrays, faces offset by the vertices of
    each object's piece): every variable is a dask array with the schema's dims and
    equals what the stages read (Artifact.read), the provenance record is in attrs;
    an unknown artifact name is one error line naming what is present."""
    scene = load_scene(write_scene(tmp_path, small_scene_dict(8)))
    run(scene, load_stagefile(PROJECT / "stages.yaml"), Workdir(tmp_path / "work"),
        until="geometry", progress=False)
    work = inspect.open_workdir(tmp_path / "work")
    assert "geometry" in work.artifacts()
    ds = work.dataset("geometry")
    artifact = open_artifact(work.artifacts()["geometry"])
    schema = load_schema("geometry")
    assert set(ds.variables) == set(artifact.names)  # uv (dims vertex, uv): a coordinate
    assert len(artifact.pieces("faces")) > 1  # several objects: the offsets matter
    for name in artifact.names:
        assert isinstance(ds[name].data, da.Array)
        assert ds[name].dims == schema.arrays[name].dims
        np.testing.assert_array_equal(ds[name].values, artifact.read(name))
    assert ds["faces"].values.max() == len(ds["vertices"]) - 1
    assert ds.attrs["prt"]["stage"] == "geometry"
    assert ds.attrs["prt"]["key"] == artifact.record["key"]
    with pytest.raises(PrtError, match="no artifact 'nope'; present: geometry"):
        work.dataset("nope")
