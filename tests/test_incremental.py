"""Incremental re-bake: exactly the stages and chunks whose declared inputs changed run."""

from __future__ import annotations

import copy
import itertools
import os
import socket
import time

import numpy as np
import pytest
from helpers import TESTS, small_scene_dict, write_scene

from pipeline.engine.chunk import Chunk, make_chunk
from pipeline.engine.chunkwrite import read_marker
from pipeline.engine.executors.local import InProcessExecutor
from pipeline.engine.planning import plan
from pipeline.engine.runner import longest_first, run
from pipeline.engine.stagefile import load_stagefile
from pipeline.engine.store import Workdir, open_artifact, read_record
from pipeline.scene.file import load_scene

STAGEFILE = TESTS / "toy" / "stages.yaml"


TILES = [f"y{y:05d}_x{x:05d}" for y in (0, 8, 16) for x in (0, 8, 16)]


def ran(report) -> dict[str, list[str]]:
    """stage -> chunk ids that ran, for the stages that ran."""
    return {r.name: r.ran_chunks for r in report if r.action == "ran"}


@pytest.fixture()
def baked(tmp_path):
    """A tiny scene baked once with the toy stage graph; returns (doc, workdir, folder)."""
    doc = small_scene_dict()
    workdir = Workdir(tmp_path / "work")
    bake(doc, tmp_path, workdir)
    return doc, workdir, tmp_path


def bake(doc, folder, workdir, **kwargs):
    scene = load_scene(write_scene(folder, doc))
    return run(scene, load_stagefile(STAGEFILE), workdir, progress=False, **kwargs)


def test_second_run_executes_nothing(baked):
    """Running twice: the second run skips every stage."""
    doc, workdir, folder = baked
    report = bake(doc, folder, workdir)
    assert ran(report) == {}
    assert {r.action for r in report} == {"skipped"}


def test_first_run_runs_every_chunk(tmp_path):
    """A fresh work directory runs every chunk of every stage; each chunk's record says
    which process ran it (this one, in-process), from when (UNIX seconds) and how long:
    the chunks of a stage one after the other."""
    workdir = Workdir(tmp_path / "w")
    before = time.time()
    report = bake(small_scene_dict(), tmp_path, workdir)
    assert ran(report) == {
        "geometry": ["floor", "box", "ball"],
        "gbuffer": TILES,
        "per_object": ["floor", "box", "ball"],
        "total": ["all"],
        "tiles": TILES,
    }
    records = sorted((read_marker(workdir.marker("tiles", tile)) for tile in TILES),
                     key=lambda r: r["started"])
    assert {r["process"] for r in records} == {f"{socket.gethostname()}:{os.getpid()}"}
    assert before <= records[0]["started"]
    for earlier, later in itertools.pairwise(records):
        assert earlier["started"] + earlier["seconds"] <= later["started"]
    assert records[-1]["started"] + records[-1]["seconds"] <= time.time()


def test_declared_param_reruns_declaring_stage_and_dependents(baked):
    """toy.scale is declared by per_object: it and its dependents (total, then tiles)
    run; geometry and gbuffer do not."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    doc["settings"] = {"toy.scale": 3.0}
    assert ran(bake(doc, folder, workdir)) == {"per_object": ["floor", "box", "ball"],
                                              "total": ["all"], "tiles": TILES}


def test_param_of_leaf_stage_reruns_only_it(baked):
    """toy.sleep is declared only by tiles, which nothing depends on."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    doc["settings"] = {"toy.sleep": 0.001}
    assert ran(bake(doc, folder, workdir)) == {"tiles": TILES}


def test_material_edit_reruns_only_chunks_reading_it(baked):
    """Editing the red material re-runs the box's chunk of per_object (and its dependents
    total and tiles); geometry and the G-buffer do not read material contents."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    doc["materials"]["red"]["albedo"] = [0.9, 0.1, 0.1]
    report = bake(doc, folder, workdir)
    assert ran(report) == {"per_object": ["box"], "total": ["all"], "tiles": TILES}
    per_object = [r for r in report if r.name == "per_object"][0]
    assert per_object.reused_chunks == ["floor", "ball"]
    value = open_artifact(workdir.artifact("per_object")).read("value")
    np.testing.assert_allclose(value[1], np.array([0.9, 0.1, 0.1]) * 2.0, rtol=1e-6)


def test_object_transform_edit_reruns_its_geometry_chunk(baked):
    """Moving the ball re-runs its geometry chunk and every G-buffer tile (any pixel may
    see the moved ball), but not the other objects' geometry chunks."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    doc["objects"]["ball"]["transform"] = {"translate": [0.7, 0.35, 0.2]}
    result = ran(bake(doc, folder, workdir))
    assert result["geometry"] == ["ball"]
    assert len(result["gbuffer"]) == 9
    assert set(result) == {"geometry", "gbuffer"}


@pytest.mark.parametrize("edit", ["unused_param", "light"])
def test_undeclared_key_reruns_nothing(baked, edit):
    """A param no stage declares, or a light (read only at render time), re-runs nothing."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    if edit == "unused_param":
        doc["settings"] = {"toy.unused": 7}
    else:
        doc["lights"][0]["position"] = [2.0, 2.0, 2.0]
    assert ran(bake(doc, folder, workdir)) == {}


def test_status_names_the_change(baked):
    """Status reports which declared param changed, without running anything."""
    doc, workdir, folder = baked
    doc = copy.deepcopy(doc)
    doc["settings"] = {"toy.scale": 3.0}
    scene = load_scene(write_scene(folder, doc))
    states = {p.spec.name: (p.state, p.reason)
              for p in plan(scene, load_stagefile(STAGEFILE), workdir)}
    assert states["per_object"] == ("stale", "param toy.scale changed (2.0 -> 3.0)")
    assert states["total"] == ("stale", "waits for per_object")
    assert states["tiles"] == ("stale", "waits for total")
    assert states["geometry"] == ("fresh", "")


def test_force_reruns_only_the_forced_stage(baked):
    """--force re-runs every chunk of that stage; its outputs are identical."""
    doc, workdir, folder = baked
    before = open_artifact(workdir.artifact("per_object")).read_all()
    report = bake(doc, folder, workdir, force=("per_object",))
    assert ran(report) == {"per_object": ["floor", "box", "ball"]}
    after = open_artifact(workdir.artifact("per_object")).read_all()
    for name in before:
        assert before[name].tobytes() == after[name].tobytes()


def test_a_rerun_hands_out_the_longest_chunks_first(baked):
    """A stage's chunks reach the executor longest first by the seconds the stage's last
    bake recorded (so the workers end on short ones), those it did not time first; a
    first bake's in plan order (test_first_run_runs_every_chunk's bake, here the
    fixture's). The artifact is the same whatever the order."""
    doc, workdir, folder = baked
    seconds = read_record(workdir.artifact("tiles"))["chunk_seconds"]
    before = open_artifact(workdir.artifact("tiles")).read_all()
    handed: list[str] = []

    class Recording(InProcessExecutor):
        def map_unordered(self, fn, tasks):
            tasks = list(tasks)
            handed.extend(t.chunk.id for t in tasks)
            return super().map_unordered(fn, tasks)

    bake(doc, folder, workdir, force=("tiles",), executor=Recording())
    assert handed == sorted(TILES, key=lambda tile: -seconds[tile])
    after = open_artifact(workdir.artifact("tiles")).read_all()
    assert all(before[name].tobytes() == after[name].tobytes() for name in before)


def test_longest_first_puts_untimed_chunks_first():
    chunks = [Chunk(c, "tile") for c in ("a", "b", "c", "d", "e")]
    order = longest_first(chunks, {"b": 1.0, "c": 3.0, "e": 1.0})
    assert [c.id for c in order] == ["a", "d", "c", "b", "e"]  # ties keep plan order


def test_until_runs_only_upstream(tmp_path):
    """--until gbuffer runs geometry and gbuffer only."""
    report = bake(small_scene_dict(), tmp_path, Workdir(tmp_path / "w"), until="gbuffer")
    assert set(ran(report)) == {"geometry", "gbuffer"}


def test_gamma_range_edit_rebakes_exactly_the_material_chunks_of_its_tiles(tmp_path):
    """In a scene with two glossy materials (the ball's Blinn-Phong, the floor's Ward),
    editing the ball's gamma_range re-runs its brdf_basis chunk and, of the glossy
    transfer and its cut (chunks by tile and material), exactly the ball's chunks of the
    tiles whose pixels see it (a chunk's key holds only its own material's basis and its
    tile's visibility); no D tile and no other material's chunk re-runs, and the result
    is bit-identical to a bake of the edited scene from scratch."""
    from pipeline import job

    doc = small_scene_dict(size=24)
    doc["methods"] = ["d2i"]
    doc["settings"] = {"gather.count": 256, "transfer.tile": 8}
    doc["materials"]["grey"] = {"model": "ward", "albedo": [0.5, 0.5, 0.5],
                                "specular": 0.1, "gamma": 0.2, "gamma_range": [0.1, 0.5]}
    workdir = Workdir(tmp_path / "w")
    job.bake(load_scene(write_scene(tmp_path, doc)), workdir, quiet=True)
    material = open_artifact(workdir.artifact("gbuffer")).read("material_id")
    ball = list(doc["materials"]).index("shiny")
    tiles = {f"y{y:05d}_x{x:05d}" for y in (0, 8, 16) for x in (0, 8, 16)
             if (material[y:y + 8, x:x + 8] == ball).any()}
    assert 0 < len(tiles) < 9  # the ball covers some tiles, not all
    grey = list(doc["materials"]).index("grey")
    assert (material == grey).any()  # the other glossy material is on screen too
    chunks = {f"{tile}/shiny" for tile in tiles}

    edited = copy.deepcopy(doc)
    edited["materials"]["shiny"]["gamma_range"] = [5, 300]
    edited_scene = load_scene(write_scene(tmp_path, edited, "edited.yaml"))
    # forecast before running (prt status, prt run --dry-run): the same chunks
    forecast = {f.name: set(f.chunks) for f in job.rebake_forecast(edited_scene, workdir)
                if f.state != "fresh"}
    report = job.bake(edited_scene, workdir, quiet=True)
    assert {name: set(chunks) for name, chunks in ran(report).items()} == forecast == {
        "brdf_basis": {"shiny"}, "d2i.transfer_t": chunks, "d2i.truncate_t": chunks}

    fresh = Workdir(tmp_path / "fresh")
    job.bake(load_scene(write_scene(tmp_path, edited, "edited.yaml")), fresh, quiet=True)
    # one copy on disk: outside the artifacts only the chunk records (small JSON)
    artifacts = sum(p.stat().st_size for p in fresh.root.glob("*.zarr/**/*") if p.is_file())
    others = [p for p in fresh.root.rglob("*") if p.is_file() and ".zarr" not in str(p)]
    assert all(p.suffix == ".json" or p.name == ".lock" for p in others)
    assert sum(p.stat().st_size for p in others) < 0.05 * artifacts
    for name in ("brdf_basis", "d2i.gather", "d2i.transfer", "d2i.transfer_t", "d2i.bounce",
                 "d2i.truncate", "d2i.truncate_t", "d2i.truncate_ms"):
        a, b = (open_artifact(w.artifact(name)).read_all() for w in (workdir, fresh))
        assert a.keys() == b.keys()
        for array in a:
            assert a[array].tobytes() == b[array].tobytes(), (name, array)


CHUNKED = TESTS / "toy" / "chunked_stages.yaml"


def test_texel_tiles_and_vertex_batches_are_planned_from_upstream_data(tmp_path):
    """A stage chunked by texel tiles gets one chunk per tile of each object's texture
    (the sizes an upstream stage recorded); one chunked by vertex batches gets runs of
    vertices per object (the geometry's vertex counts). Their pieces cover exactly the
    textures' texels and the geometry's vertices; changing the atlas re-plans the tiles."""
    import math

    doc = small_scene_dict()
    scene = load_scene(write_scene(tmp_path, doc))
    workdir = Workdir(tmp_path / "w")
    report = run(scene, load_stagefile(CHUNKED), workdir, progress=False)
    sizes = open_artifact(workdir.artifact("atlas")).attrs["texture_sizes"]
    tiles = [f"{obj}/y{y:05d}_x{x:05d}" for obj, (h, w) in sizes.items()
             for y in range(0, h, 4) for x in range(0, w, 4)]
    assert ran(report)["texels"] == tiles
    texels = open_artifact(workdir.artifact("texels")).read("texels")
    assert int(texels.sum()) == sum(h * w for h, w in sizes.values())

    geometry = open_artifact(workdir.artifact("geometry"))
    counts = geometry.attrs["vertex_counts"]
    starts = [(obj, n * i // -(-n // 7)) for obj, n in counts.items() for i in range(-(-n // 7))]
    assert ran(report)["vertex_sums"] == [f"{obj}/v{s:08d}" for obj, s in starts]
    sums = open_artifact(workdir.artifact("vertex_sums"))
    for obj in counts:  # even runs per object, none a short remainder
        runs = [sums.read_piece("vertices", c).shape[0] for c in ran(report)["vertex_sums"]
                if c.startswith(f"{obj}/")]
        assert sum(runs) == counts[obj] and max(runs) <= 7 and max(runs) - min(runs) <= 1
    vertices = open_artifact(workdir.artifact("vertex_sums")).read("vertices")
    assert vertices.tobytes() == geometry.read("vertices").tobytes()

    doc["settings"] = {"toy.texels_per_vertex": 2.0}
    report = run(load_scene(write_scene(tmp_path, doc)), load_stagefile(CHUNKED), workdir,
                 progress=False)
    sizes = open_artifact(workdir.artifact("atlas")).attrs["texture_sizes"]
    assert sizes["box"][0] == math.ceil(math.sqrt(counts["box"] * 2.0))
    assert set(ran(report)) == {"atlas", "texels"}
    assert len(ran(report)["texels"]) == sum(-(-h // 4) * -(-w // 4) for h, w in
                                             sizes.values())


def test_a_chunk_cut_anew_under_the_same_id_re_runs(tmp_path, monkeypatch):
    """A chunk's key holds its coordinates, not only its id: when the chunker cuts the
    same ids over other vertices (new chunker code, same params and inputs), those chunks
    re-run, `prt status` says why, and the artifact equals a bake from scratch (before the
    fix, the old pieces were reused and the artifact held the old runs' vertices)."""
    from pipeline.engine import chunking

    doc = small_scene_dict()
    scene = load_scene(write_scene(tmp_path, doc))
    stagefile = load_stagefile(CHUNKED)
    workdir = Workdir(tmp_path / "w")
    run(scene, stagefile, workdir, progress=False)

    planned = chunking.CHUNKERS["vertex_batch"]
    moved: set[str] = set()

    def recut(spec, scene, params, upstream):
        """The same ids; each object's first run hands its last vertex to the second."""
        chunks = planned(spec, scene, params, upstream)
        out = list(chunks)
        for i, (a, b) in enumerate(itertools.pairwise(chunks)):
            if a.object == b.object and a.span[0] == 0:
                out[i] = make_chunk(a.id, a.kind, object=a.object, span=(0, a.span[1] - 1))
                out[i + 1] = make_chunk(b.id, b.kind, object=b.object,
                                        span=(a.span[1] - 1, b.span[1]))
                moved.update((a.id, b.id))
        return out

    monkeypatch.setitem(chunking.CHUNKERS, "vertex_batch", recut)
    states = {p.spec.name: (p.state, p.reason) for p in plan(scene, stagefile, workdir)}
    assert states["vertex_sums"] == ("stale", "chunk layout changed")
    report = run(scene, stagefile, workdir, progress=False)
    assert moved and sorted(ran(report)["vertex_sums"]) == sorted(moved)
    assert set(ran(report)) == {"vertex_sums"}
    scratch = Workdir(tmp_path / "scratch")
    run(scene, stagefile, scratch, progress=False)
    assert read_record(workdir.artifact("vertex_sums"))["digest"] == \
        read_record(scratch.artifact("vertex_sums"))["digest"]


def test_status_blames_the_atlas_not_the_geometry_when_the_tiles_change(tmp_path):
    """A texel-tiled stage whose atlas changed size (a camera move, for triple.visibility)
    names the atlas as the changed input, not the unchanged geometry it also reads (the
    geometry's part of the explanation must not depend on how many tiles there are)."""
    doc = small_scene_dict()
    workdir = Workdir(tmp_path / "w")
    run(load_scene(write_scene(tmp_path, doc)), load_stagefile(CHUNKED), workdir,
        progress=False)
    doc["settings"] = {"toy.texels_per_vertex": 2.0}
    scene = load_scene(write_scene(tmp_path, doc))
    run(scene, load_stagefile(CHUNKED), workdir, progress=False, until="atlas")
    states = {p.spec.name: (p.state, p.reason)
              for p in plan(scene, load_stagefile(CHUNKED), workdir)}
    assert states["geometry"] == ("fresh", "")
    assert states["atlas"] == ("fresh", "")
    assert states["texels"] == ("stale", "input atlas changed")


MATERIAL_TILES = TESTS / "toy" / "material_tiles_stages.yaml"


def test_tile_material_chunks_split_tiles_and_read_only_their_parent_tile(tmp_path):
    """Chunking ``tile_material``: one chunk per pixel tile and glossy material seen in
    it (``skip_models: [lambert]``), id TILE/MATERIAL, holding exactly that material's
    pixels of the tile. A chunk's key holds its parent tile's digest and no other tile's
    (a changed digest of one tile re-keys exactly that tile's chunks), and its own
    material's sections only (an albedo edit of one material re-runs exactly its
    chunks, and the result equals a bake from scratch)."""
    from pipeline.engine.planning import plan_stage, stage_params

    doc = small_scene_dict(size=24)
    doc["materials"]["grey"] = {"model": "ward", "albedo": [0.5, 0.5, 0.5],
                                "specular": 0.1, "gamma": 0.2, "gamma_range": [0.1, 0.5]}
    stagefile = load_stagefile(MATERIAL_TILES)
    scene = load_scene(write_scene(tmp_path, doc))
    workdir = Workdir(tmp_path / "w")
    report = run(scene, stagefile, workdir, progress=False)
    material = open_artifact(workdir.artifact("gbuffer")).read("material_id")
    names = list(doc["materials"])
    expected = [f"y{y:05d}_x{x:05d}/{m}" for y in (0, 8, 16) for x in (0, 8, 16)
                for m in names if m != "red"
                and (material[y:y + 8, x:x + 8] == names.index(m)).any()]
    assert ran(report)["material_values"] == expected
    assert any(c.endswith("/shiny") for c in expected) and any(c.endswith("/grey")
                                                                for c in expected)
    values = open_artifact(workdir.artifact("material_values"))
    pixels = np.sort(values.read("pixel"))
    glossy = np.isin(material.reshape(-1), [names.index("shiny"), names.index("grey")])
    np.testing.assert_array_equal(pixels, np.flatnonzero(glossy))

    spec = stagefile.stages["material_values"]
    params = stage_params(stagefile, scene)
    before = plan_stage(spec, scene, stagefile, workdir, params)
    record = dict(open_artifact(workdir.artifact("tiles")).record)
    record["chunk_digests"] = {**record["chunk_digests"], "y00008_x00008": "changed"}
    after = plan_stage(spec, scene, stagefile, workdir, params,
                       input_records={"tiles": record})
    rekeyed = {c for c in before.chunk_keys if before.chunk_keys[c] != after.chunk_keys[c]}
    assert rekeyed == {c for c in expected if c.startswith("y00008_x00008/")} != set()

    edited = copy.deepcopy(doc)
    edited["materials"]["shiny"]["albedo"] = [0.5, 0.4, 0.6]
    edited_scene = load_scene(write_scene(tmp_path, edited, "edited.yaml"))
    report = run(edited_scene, stagefile, workdir, progress=False)
    assert ran(report) == {"material_values": [c for c in expected if c.endswith("/shiny")]}
    fresh = Workdir(tmp_path / "fresh")
    run(edited_scene, stagefile, fresh, progress=False)
    a, b = (open_artifact(w.artifact("material_values")).read_all() for w in (workdir, fresh))
    assert all(a[n].tobytes() == b[n].tobytes() for n in a)
