"""pipeline.inspect: a work directory's artifacts as lazy xarray Datasets."""

from __future__ import annotations

import subprocess
import sys

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

sys.path.insert(0, str(PROJECT / "examples"))  # the example scripts' functions


def run_example(script: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python examples/<script>.py ARGS`` as a user runs it; it must exit 0."""
    result = subprocess.run([sys.executable, str(PROJECT / "examples" / f"{script}.py"),
                             *map(str, args)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result


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


def test_chunk_times_example_charts_the_records_chunk_seconds(tmp_path):
    """examples/chunk_times.py from the command line on a small scene's geometry: it
    writes a PNG and its bars are the record's chunk seconds, one per chunk, in the
    stage's chunk order."""
    from matplotlib.image import imread

    scene = load_scene(write_scene(tmp_path, small_scene_dict(8)))
    run(scene, load_stagefile(PROJECT / "stages.yaml"), Workdir(tmp_path / "work"),
        until="geometry", progress=False)
    out = tmp_path / "times.png"
    result = run_example("chunk_times", str(tmp_path / "work"), "geometry", "--out", str(out))
    record = open_artifact(tmp_path / "work" / "geometry.zarr").record
    assert f"({len(record['chunks'])} chunks)" in result.stdout
    assert imread(out).shape[2] in (3, 4)

    from chunk_times import chunk_times_figure

    seconds = chunk_times_figure(tmp_path / "work", "geometry", tmp_path / "again.png")
    assert list(seconds) == record["chunks"]
    assert seconds == {c: record["chunk_seconds"][c] for c in record["chunks"]}


def test_sg_lobes_example_reads_slot_zero_at_the_normal_view(tmp_path):
    """examples/sg_lobes_over_mesh.py on a tiny sg bake (a glossy icosphere over a
    Lambert floor, grid 9 × 16, no indirect paths): from the command line it writes a
    PNG; its σ per glossy vertex equals slot 0's λ at the view nearest the normal read
    with Artifact.read, and only vertices that store a slot (the sphere's) appear."""
    from test_sg import sg_lights_map

    from pipeline.images import write_exr
    from pipeline.stages.sg_fit import slot_counts

    write_exr(tmp_path / "env.exr", sg_lights_map().astype(np.float32))
    doc = small_scene_dict(8)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 0
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / "env.exr")}]
    doc["settings"] = {"sg.fit_grid": [9, 16], "sg.fit_batch": 64, "sg.indirect_samples": 0}
    scene = load_scene(write_scene(tmp_path, doc))
    run(scene, load_stagefile(PROJECT / "stages.yaml"), Workdir(tmp_path / "work"),
        until="sg.relax", progress=False)
    out = tmp_path / "lobes.png"
    run_example("sg_lobes_over_mesh", str(tmp_path / "work"), "--out", str(out))
    assert out.stat().st_size > 0

    from sg_lobes_over_mesh import normal_view_sigma

    glossy, _, count, sigma = normal_view_sigma(tmp_path / "work")
    relax = open_artifact(tmp_path / "work" / "sg.relax.zarr")
    geometry = open_artifact(tmp_path / "work" / "geometry.zarr")
    rows, first = relax.read("lobes"), relax.read("first")
    np.testing.assert_array_equal(glossy, np.flatnonzero(slot_counts(first, len(rows))))
    ball = geometry.read("object_ranges")[geometry.attrs["object_names"].index("ball")]
    assert glossy.min() >= ball[0] and glossy.max() < ball[1] and len(glossy) == 12
    nearest = np.argmax(geometry.read("normals")[glossy] @ relax.read("views").T, axis=1)
    lam = rows[first[glossy], nearest, 6]
    np.testing.assert_allclose(sigma, np.degrees(1 / np.sqrt(lam)), rtol=1e-6)
    np.testing.assert_array_equal(count, relax.read("count")[glossy])


def test_brdf_basis_example_reads_one_materials_basis(tmp_path):
    """examples/brdf_basis.py on the default Cornell box's brdf_basis: from the command
    line it writes a PNG for the first glossy material; its arrays are that material's
    row of the artifact (first k basis rows), k is the smallest count whose worst
    relative RMS is within the tolerance (or the cap), and an unknown material is one
    error line naming those present."""
    from pipeline import job

    scene = job.open_scene(None)
    run(scene, load_stagefile(PROJECT / "stages.yaml"), Workdir(tmp_path / "work"),
        until="brdf_basis", progress=False)
    out = tmp_path / "basis.png"
    run_example("brdf_basis", str(tmp_path / "work"), "--out", str(out))
    assert out.stat().st_size > 0

    from brdf_basis import material_basis

    artifact = open_artifact(tmp_path / "work" / "brdf_basis.zarr")
    names = artifact.attrs["material_names"]
    b = material_basis(tmp_path / "work")
    m = names.index(b["name"])
    assert b["k"] == artifact.read("k")[m] > 0
    assert all(artifact.read("k")[i] == 0 for i in range(m))  # the first glossy one
    np.testing.assert_array_equal(b["basis"], artifact.read("basis")[m, :b["k"]])
    np.testing.assert_array_equal(b["mean"], artifact.read("mean")[m])
    worst = b["worst_rel_rms"]
    assert worst[b["k"]] <= b["tolerance"] or b["k"] == artifact.attrs["max_k"]
    assert np.all(worst[:b["k"]] > b["tolerance"])
    with pytest.raises(PrtError, match="no material 'nope'; present: "):
        material_basis(tmp_path / "work", "nope")
