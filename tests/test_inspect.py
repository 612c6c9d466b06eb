"""pipeline.engine.inspect: a work directory's artifacts as lazy xarray Datasets."""

from __future__ import annotations

import subprocess
import sys

import dask.array as da
import numpy as np
import pytest
from helpers import PROJECT, small_scene_dict, write_scene

from pipeline import job
from pipeline.engine import inspect
from pipeline.engine.runner import run
from pipeline.engine.schema import load_schema
from pipeline.engine.store import Workdir, open_artifact
from pipeline.errors import PrtError
from pipeline.scene.file import load_scene

sys.path.insert(0, str(PROJECT / "examples"))  # the example scripts' functions


def run_example(script: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python examples/<script>.py ARGS`` as a user runs it; it must exit 0."""
    result = subprocess.run([sys.executable, str(PROJECT / "examples" / f"{script}.py"),
                             *map(str, args)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result


def bake_and_draw(tmp_path, doc: dict, until: str, script: str) -> Workdir:
    """Bake ``doc`` up to ``until`` in tmp_path/work, then run examples/<script>.py on it
    from the command line: it must write a non-empty PNG. Returns the work directory."""
    from pipeline import job

    scene = load_scene(write_scene(tmp_path, doc))
    workdir = job.workdir_for(scene, tmp_path / "work")
    job.bake(scene, workdir, until=until, quiet=True)
    out = tmp_path / f"{script}.png"
    run_example(script, str(tmp_path / "work"), "--out", str(out))
    assert out.stat().st_size > 0
    return workdir


def test_an_artifact_opens_lazily_with_its_schema_dims_and_provenance(tmp_path):
    """The geometry of a small scene (segmented arrays, faces offset by the vertices of
    each object's piece): every variable is a dask array with the schema's dims and
    equals what the stages read (Artifact.read), the provenance record is in attrs;
    an unknown artifact name is one error line naming what is present."""
    scene = load_scene(write_scene(tmp_path, small_scene_dict(8)))
    run(scene, job.stages(), Workdir(tmp_path / "work"),
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
    run(scene, job.stages(), Workdir(tmp_path / "work"),
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
    from pipeline.methods.sg.stages.fit import slot_counts

    write_exr(tmp_path / "env.exr", sg_lights_map().astype(np.float32))
    doc = small_scene_dict(8)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 0
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / "env.exr")}]
    doc["settings"] = {"sg.fit_grid": [9, 16], "sg.fit_batch": 64, "sg.indirect_samples": 0}
    scene = load_scene(write_scene(tmp_path, doc))
    run(scene, job.stages(), Workdir(tmp_path / "work"),
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
    run(scene, job.stages(), Workdir(tmp_path / "work"),
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


def test_basis_of_rows_is_the_place_in_the_pixels_run():
    from transfer_sparsity import basis_of_rows

    np.testing.assert_array_equal(basis_of_rows(np.array([5, 5, 5, 7, 7, 9, 2, 2])),
                                  [0, 1, 2, 0, 1, 0, 0, 1])
    assert len(basis_of_rows(np.zeros(0, np.int32))) == 0


def test_transfer_sparsity_example_splits_t_by_basis(tmp_path):
    """examples/transfer_sparsity.py on a tiny d2i bake (the ball glossy): from the
    command line it writes a PNG; its rows per basis partition T's rows, b0 has one row
    per glossy pixel, there are k + 1 bases for the ball's k, and each basis's counts are
    those rows' t_count (T in d2i.transfer_t, D in d2i.transfer)."""
    from transfer_sparsity import basis_of_rows, sparsity


    doc = small_scene_dict(16)
    doc["methods"] = ["d2i"]
    doc["settings"] = {"gather.count": 256, "transfer.tile": 8}
    workdir = bake_and_draw(tmp_path, doc, "d2i.transfer_t", "transfer_sparsity")

    s = sparsity(tmp_path / "work")
    transfer = open_artifact(workdir.artifact("d2i.transfer"))
    glossy = open_artifact(workdir.artifact("d2i.transfer_t"))
    basis = open_artifact(workdir.artifact("brdf_basis"))
    k = basis.read("k")[basis.attrs["material_names"].index("shiny")]
    t_pixel, t_count = glossy.read("t_pixel"), glossy.read("t_count")
    assert [n for n in s["rows"]] == [f"b{b}" for b in range(k + 1)] + ["D"]
    assert len(s["rows"]["b0"]["count"]) == len(np.unique(t_pixel)) > 0
    assert sum(len(s["rows"][f"b{b}"]["count"]) for b in range(k + 1)) == len(t_pixel)
    for b in range(k + 1):
        np.testing.assert_array_equal(s["rows"][f"b{b}"]["count"],
                                      t_count[basis_of_rows(t_pixel) == b])
    np.testing.assert_array_equal(s["rows"]["D"]["count"], transfer.read("d_count"))


def test_visibility_texture_example_integrates_the_stored_rows(tmp_path):
    """examples/visibility_texture.py on a tiny triple bake: from the command line it
    writes a PNG; each object's texture has the atlas's size, is NaN exactly on its empty
    texels, and its fractions equal ∫V dω / 2π of the rows inverse-transformed to the
    leaves (to float32 rounding: the scaling coefficients are always kept); the floor
    sees open sky somewhere and is shadowed somewhere."""
    from visibility_texture import open_fractions

    from pipeline.images import write_exr
    from pipeline.math.sphwavelet import wavelet_basis

    rgb = np.full((16, 32, 3), 0.5, np.float32)
    write_exr(tmp_path / "env.exr", rgb)
    doc = small_scene_dict(16)
    doc["methods"] = ["triple"]
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / "env.exr")}]
    doc["settings"] = {"triple.leaf_level": 3, "triple.frame_grid": [16, 9, 16],
                       "triple.view_grid": [16, 8], "triple.light_block": 576,
                       "triple.store_budget": 320, "triple.light_budget": 320}
    workdir = bake_and_draw(tmp_path, doc, "triple.visibility", "visibility_texture")

    fractions = open_fractions(tmp_path / "work")
    vis = open_artifact(workdir.artifact("triple.visibility"))
    atlas = open_artifact(workdir.artifact("triple.atlas"))
    basis = wavelet_basis(vis.attrs["leaf_level"])
    count, start = vis.read("count"), vis.read("start")
    index, value = vis.read("index"), vis.read("value")
    texel_row, state = vis.read("texel_row"), atlas.read("texel_state")
    offsets = atlas.read("texture_offsets")
    for (name, texture), offset in zip(fractions.items(), offsets, strict=True):
        height, width = vis.attrs["texture_sizes"][name]
        assert texture.shape == (height, width)
        empty = state[offset:offset + height * width].reshape(height, width) == 0
        np.testing.assert_array_equal(np.isnan(texture), empty)
        rows = texel_row[offset:offset + height * width][~empty.ravel()][::7]
        for r, expected in zip(rows, texture[~empty][::7], strict=True):
            dense = np.zeros(basis.size)
            s = slice(start[r], start[r] + count[r])
            dense[index[s]] = value[s]
            integral = basis.inverse(dense) @ basis.leaf_areas() / (2 * np.pi)
            assert abs(integral - expected) < 1e-5
    floor = fractions["floor"]
    assert np.nanmax(floor) > 0.95 and np.nanmin(floor) < 0.8
