"""Bakes whose visibility rays the device traces (``bake.device: device``: the BVH kernel
of pipeline/device/bvh.py, here on the CPU OpenCL device the suite runs on) against
Embree's (``embree``): issue 44's "same answers".

The two intersect float32 triangles by different formulas, so a ray that passes within
rounding of an edge may be blocked for one and free for the other. Each stage's rays are
therefore recorded as the stage casts them (Embree answering), traced again by the
device, and every ray whose answers differ must be one whose own answer is not stable:
Embree gives the device's answer for the ray moved by a few ulps of the scene's size
(tests/test_bvh.py ``unstable``); such rays must be rare (≤ 1 in 2,000). A bake on the
device is bit-reproducible run to run, and its key differs from Embree's, so neither
takes the other's place."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import write_scene
from test_bvh import unstable
from test_triple_bake import SETTINGS, scene_doc

from pipeline import job
from pipeline.device.bvh import DeviceRayTracer
from pipeline.device.raytrace import RayTracer
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.scene.file import load_scene

STAGEFILE = job.stages()
# Unstable rays are ≤ 1 in 2,000 of random ones (tests/test_bvh.py); the stages' rays are
# not random: sg's visibility maps cast rays along the axes from the floor's corner and
# edge vertices, exactly along its edges (0.4 % of the tiny scene's map rays)
RARE = 100


class RecordingTracer:
    """Embree's ``occluded`` and ``intersect``, every call's rays and answers kept
    (``rays``; ``hits``: origins, directions and Embree's Hits)."""

    def __init__(self, tracer: RayTracer) -> None:
        self.tracer, self.threads, self.rays, self.hits = tracer, 1, [], []

    def intersect(self, origins, directions):
        hits = self.tracer.intersect(origins, directions)
        self.hits.append((np.array(origins, np.float32).reshape(-1, 3),
                          np.array(directions, np.float32).reshape(-1, 3), hits))
        return hits

    def occluded(self, origins, directions, distances, threads=None):
        answer = self.tracer.occluded(origins, directions, distances, threads=1)
        self.rays.append((np.array(origins, np.float32).reshape(-1, 3),
                          np.array(directions, np.float32).reshape(-1, 3),
                          np.array(distances, np.float32).reshape(-1), answer))
        return answer


def assert_same_answers(recorder: RecordingTracer, vertices, faces) -> None:
    """The recorded rays (those of positive length: a stage gives the others a negative
    one, no ray) traced by the device: equal to Embree's but on unstable rays. Those
    are rare (≤ 1 in RARE) apart from rays that start on a surface, where Embree counts
    a hit at t = 0 and the device does not (the tiny scene's box stands on the floor:
    its bottom face's texels and vertices, offset by ε below it, start on the floor's
    plane; the face is against the floor, never seen)."""
    o, d, t, expected = (np.concatenate(part) for part in zip(*recorder.rays, strict=True))
    cast = t > 0
    o, d, t, expected = o[cast], d[cast], t[cast], expected[cast]
    got = DeviceRayTracer(vertices, faces).occluded(o, d, t)
    assert len(t) > 1000 and 0.05 < expected.mean() < 0.95  # shadows and open sky
    differ = np.flatnonzero(got != expected)
    scale = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    ends = np.where(np.isfinite(t[differ]), t[differ], 2.0 * scale)  # a finite segment
    ok = unstable(recorder.tracer, o[differ].astype(np.float64),
                  d[differ].astype(np.float64), ends, got[differ], scale)
    assert np.all(ok), f"{int((~ok).sum())} rays differ away from any edge"
    on_surface = recorder.tracer.intersect(o[differ], d[differ]).t == 0.0
    assert (~on_surface).sum() <= len(t) // RARE, \
        f"{int((~on_surface).sum())} of {len(t)} rays differ"


def assert_same_hits(recorder: RecordingTracer, vertices, faces) -> None:
    """The recorded closest-hit rays traced by the device: on Embree's faces except on
    rays Embree itself sends to the device's face when nudged by 1e-5 of the scene
    or to a face at the device's distance (a tie between coincident faces), those ≤ 1 in
    RARE, and rays that start on a surface (Embree's hit at t = 0); on the same face
    their distances agree to float32 rounding (1e-5 of the scene: the two
    compute t by different formulas, each rounding a few ulps)."""
    o, d, expected = (np.concatenate(part) for part in zip(
        *[(o, d, h.prim) for o, d, h in recorder.hits], strict=True))
    t = np.concatenate([h.t for _, _, h in recorder.hits])
    got = DeviceRayTracer(vertices, faces).intersect(o, d)
    assert len(o) > 1000 and 0.05 < (expected >= 0).mean() < 0.95  # hits and escapes
    scale = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    same = got.prim == expected
    hit = same & (expected >= 0)
    assert np.all(np.abs(got.t[hit] - t[hit]) <= 1e-5 * scale)
    # a ray that starts on a surface: Embree's hit at t = 0, none for the device (as
    # assert_same_answers says); the rest must be rare and unstable
    differ = np.flatnonzero(~same & ~((t == 0.0) & (got.prim < 0)))
    assert len(differ) <= len(o) // RARE, f"{len(differ)} of {len(o)} rays differ"
    for i in differ:  # Embree's answer for the ray nudged: the device's face, or a hit
        # at the device's distance on another face (a tie between coincident faces: the
        # box's bottom on the floor), or no hit where the device has none
        nudges = unit_steps() * 1e-5 * scale
        hits = recorder.tracer.intersect(np.repeat(o[i:i + 1], len(nudges), 0) + nudges,
                                         np.repeat(d[i:i + 1], len(nudges), 0))
        if got.prim[i] < 0:
            assert (hits.prim < 0).any(), (i, expected[i])
            continue
        tie = (hits.prim >= 0) & (np.abs(hits.t - got.t[i]) <= 1e-4 * scale)
        assert got.prim[i] in hits.prim or tie.any(), (i, got.prim[i], expected[i])


def bake_triple(folder, device: str) -> Workdir:
    folder.mkdir(parents=True)
    doc = scene_doc()
    doc["settings"] = {**SETTINGS, "bake.device": device}
    workdir = Workdir(folder / f"work-{device}")
    run(load_scene(write_scene(folder, doc)), STAGEFILE, workdir, until="triple.visibility",
        progress=False)
    return workdir


@pytest.fixture(scope="module")
def triple_bakes(tmp_path_factory):
    """The tiny triple scene baked by Embree, and twice by the device: work directories."""
    folder = tmp_path_factory.mktemp("bake_device")
    return {name: bake_triple(folder / name, device) for name, device in
            (("embree", "embree"), ("device", "device"), ("again", "device"))}


def test_triple_visibility_rays_on_the_device_answer_as_embree(triple_bakes):
    """Every ray triple.visibility casts on the tiny scene (every object's texels),
    through the stage's own batching, answered by both."""
    from test_triple_bake import OBJECTS, piece

    from pipeline.methods.triple.stages.visibility import visibility_leaf_means
    from pipeline.methods.triple.texels import EMPTY
    from pipeline.stages.geometry import traced_geometry

    workdir = triple_bakes["embree"]
    geometry = open_artifact(workdir.artifact("geometry"))
    atlas = open_artifact(workdir.artifact("triple.atlas"))
    traced = traced_geometry(geometry)
    recorder = RecordingTracer(traced.tracer)
    for obj in OBJECTS:
        filled = piece(atlas, "texel_state", obj) != EMPTY
        first = geometry.read("object_ranges")[OBJECTS.index(obj), 2]
        at = {n: piece(atlas, n, obj)[filled].astype(np.float64)
              for n in ("texel_position", "texel_normal", "texel_tangent")}
        visibility_leaf_means(recorder, at["texel_position"], at["texel_normal"],
                              at["texel_tangent"], traced.mesh.face_normal[
                                  first + piece(atlas, "texel_face", obj)[filled]],
                              traced.epsilon, SETTINGS["triple.leaf_level"],
                              SETTINGS["triple.visibility_refine"])
    assert_same_answers(recorder, traced.mesh.vertices, traced.mesh.faces)


def test_triple_visibility_on_the_device_is_reproducible_and_keyed_apart(triple_bakes):
    """The device's bake twice: the same bytes, under one key, which is not Embree's;
    the stage records say who traced."""
    embree, device, again = (open_artifact(triple_bakes[k].artifact("triple.visibility"))
                             for k in ("embree", "device", "again"))
    for name in ("count", "start", "index", "value", "texel_row"):
        assert np.array_equal(device.read(name), again.read(name)), name
    assert device.record["key"] == again.record["key"] != embree.record["key"]
    assert device.record["key_parts"]["params"]["bake.device"] == "device"
    assert embree.record["key_parts"]["params"]["bake.device"] == "embree"


def bake_d2i(folder, device: str, gathers: int = 256) -> Workdir:
    """The tiny d2i scene at 16² with ``gathers`` gather samples, baked through
    d2i.transfer and d2i.bounce by ``device``."""
    from tiny_scenes import tiny_scene

    scene = tiny_scene(folder, "d2i", 16)
    scene = scene.with_settings({"gather.count": gathers, "bake.device": device})
    workdir = Workdir(folder / f"work-{device}")
    run(scene, STAGEFILE, workdir, until=("d2i.transfer", "d2i.bounce"), progress=False)
    return workdir


def test_d2i_visibility_rays_on_the_device_answer_as_embree(tmp_path):
    """The rays of d2i.transfer (pixels to gather-disk centres) and d2i.bounce (disk to
    disk) on the tiny scene, through center_visibility, answered by both."""
    from pipeline.methods.d2i.stages.transfer import center_visibility, gather_disks
    from pipeline.stages.geometry import traced_geometry

    workdir = bake_d2i(tmp_path / "embree", "embree")
    geometry = open_artifact(workdir.artifact("geometry"))
    gbuffer = open_artifact(workdir.artifact("gbuffer"))
    disks = gather_disks(open_artifact(workdir.artifact("d2i.gather")))
    traced = traced_geometry(geometry)
    recorder = RecordingTracer(traced.tracer)
    seen = gbuffer.read("material_id").reshape(-1) >= 0
    for position, normal in ((gbuffer.read("position").reshape(-1, 3)[seen],
                              gbuffer.read("normal").reshape(-1, 3)[seen]),
                             (disks.center, disks.normal)):
        center_visibility(recorder, position.astype(np.float64), normal.astype(np.float64),
                          disks, traced.epsilon)
    assert_same_answers(recorder, traced.mesh.vertices, traced.mesh.faces)


def test_d2i_transfer_on_the_device_is_reproducible_and_keyed_apart(tmp_path):
    """d2i.gather, d2i.transfer and d2i.bounce baked twice by the device: the same
    bytes, one key each, not Embree's."""
    bakes = {name: bake_d2i(tmp_path / name, device) for name, device in
             (("embree", "embree"), ("device", "device"), ("again", "device"))}
    for stage, names in (("d2i.gather", ("position", "area", "face")),
                         ("d2i.transfer", ("d_count", "d_index", "d_value")),
                         ("d2i.bounce", ("ms_count", "ms_index", "ms_value"))):
        embree, device, again = (open_artifact(bakes[k].artifact(stage))
                                 for k in ("embree", "device", "again"))
        for name in names:
            assert np.array_equal(device.read(name), again.read(name)), (stage, name)
        assert device.record["key"] == again.record["key"] != embree.record["key"]


def test_the_command_line_chooses_and_states_who_traces(tmp_path):
    """``prt run --bake-device device`` bakes with the device and records it; a later
    ``prt status`` with the default (auto: Embree on a CPU device, the device on a GPU)
    sees that bake as stale where auto chooses Embree; ``prt devices`` states auto's
    choice."""
    from test_cli import prt
    from tiny_scenes import tiny_scene

    from pipeline.device.bake_tracer import device_is_gpu

    scene = tiny_scene(tmp_path, "triple").path
    workdir = tmp_path / "work"
    done = prt("run", scene, "--until", "triple.visibility", "--bake-device", "device",
               "--workdir", workdir, "-q")
    assert done.returncode == 0, done.stderr
    record = open_artifact(Workdir(workdir).artifact("triple.visibility")).record
    assert record["key_parts"]["params"]["bake.device"] == "device"
    status = prt("status", scene, "--workdir", workdir)
    assert status.returncode == 0, status.stderr
    line = next(x for x in status.stdout.splitlines() if "triple.visibility" in x)
    assert ("fresh" in line) == device_is_gpu(), line
    devices = prt("devices")
    auto = "device" if device_is_gpu() else "embree"
    assert f"bake rays: {auto} (auto: " in devices.stdout, devices.stdout
    bad = prt("run", scene, "--bake-device", "gpu", "--workdir", workdir)
    assert bad.returncode == 2 and "gpu" in bad.stderr


def test_a_scene_setting_auto_is_resolved_and_a_wrong_one_named(tmp_path):
    """``settings: {bake.device: auto}`` enters the keys as this machine's choice; any
    other word is one error naming the scene file and the setting."""
    from pipeline.device.bake_tracer import resolve
    from pipeline.engine.planning import stage_params
    from pipeline.errors import PrtError

    doc = scene_doc()
    doc["settings"] = {**SETTINGS, "bake.device": "auto"}
    scene = load_scene(write_scene(tmp_path, doc))
    assert stage_params(STAGEFILE, scene)["bake.device"] == resolve("auto") != "auto"
    doc["settings"]["bake.device"] = "gpu"
    path = write_scene(tmp_path, doc, "wrong.yaml")
    with pytest.raises(PrtError, match=r"wrong\.yaml: settings\.bake\.device: 'gpu': expected"):
        stage_params(STAGEFILE, load_scene(path))


def test_d2i_gather_hits_on_the_device_are_embree_s(tmp_path):
    """d2i.gather's photon rays (uniform and glossy, through its _Shooter) and its area
    samples' visibility rays on the tiny scene, answered by both (assert_same_hits,
    assert_same_answers)."""
    from pipeline.methods.d2i.stages.gather import _Seen, _Shooter
    from pipeline.stages.geometry import traced_geometry

    workdir = bake_d2i(tmp_path / "embree", "embree")
    geometry = open_artifact(workdir.artifact("geometry"))
    gbuffer = open_artifact(workdir.artifact("gbuffer"))
    traced = traced_geometry(geometry)
    recorder = RecordingTracer(traced.tracer)
    position = gbuffer.read("position").reshape(-1, 3).astype(np.float64)
    normal = gbuffer.read("normal").reshape(-1, 3).astype(np.float64)
    seen = np.flatnonzero(gbuffer.read("material_id").reshape(-1) >= 0)
    eye = np.asarray(load_scene(write_scene(tmp_path, scene_doc())).camera.position)
    shoot = _Shooter(recorder, traced.mesh, position, normal, eye, traced.epsilon,
                     np.random.default_rng(5))
    samples = shoot(seen, 3000, exponent=None)
    shoot(seen, 1000, exponent=200.0)
    start = position[samples["source_pixel"]] + traced.epsilon * normal[samples["source_pixel"]]
    # each sample against another one's view sample, as area samples are tested
    _Seen(recorder, start, traced.epsilon)(np.random.default_rng(6).permutation(len(start)),
                                           samples["position"], samples["normal"])
    assert_same_answers(recorder, traced.mesh.vertices, traced.mesh.faces)
    assert_same_hits(recorder, traced.mesh.vertices, traced.mesh.faces)


def unit_steps() -> np.ndarray:
    """The 26 unit directions to a cube's faces, edges and corners."""
    steps = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                      if (x, y, z) != (0, 0, 0)], np.float64)
    return steps / np.linalg.norm(steps, axis=1, keepdims=True)


def test_sg_rays_on_the_device_are_embree_s(tmp_path):
    """The rays of sg.diffuse (its transfer's cosine rays and bounces), sg.visibility
    (the maps' rays, the occluders' rays), sg.fit's transport (its visibility and
    indirect rays) and sg.source_visibility (a source's circle of rays), all closest
    hits, on the tiny sg scene, through the stages' own VertexScene, answered by both."""
    from tiny_scenes import tiny_scene

    from pipeline.math.brdf import BrdfParams
    from pipeline.methods.sg import diffuse, source_rings, transport, visibility
    from pipeline.methods.sg.vertex_scene import VertexScene

    scene = tiny_scene(tmp_path, "sg")
    workdir = Workdir(tmp_path / "work")
    run(scene, STAGEFILE, workdir, until="geometry", progress=False)
    geometry = open_artifact(workdir.artifact("geometry"))
    arrays = {name: geometry.read(name) for name in
              ("vertices", "normals", "faces", "object_ranges", "object_material")}
    materials = [BrdfParams("lambert", (0.5, 0.5, 0.5)) for _ in
                 geometry.attrs["material_names"]]
    recorder = RecordingTracer(RayTracer(arrays["vertices"], arrays["faces"]))
    vertex_scene = VertexScene.from_arrays(arrays, materials, recorder)
    rng = np.random.default_rng(7)
    transfer = diffuse.transfer(vertex_scene, 16, 1, rng, 256, 3)
    every = np.arange(len(vertex_scene.positions))
    visibility.visibility_maps(vertex_scene, every, 4, 1)
    visibility.occluder_transfer(vertex_scene, every, transfer, 16, rng)
    glossy = [BrdfParams("blinn_phong", (0.3, 0.3, 0.3), (0.2, 0.2, 0.2), 40.0)] * len(materials)
    sphere = np.array([[0.0, 1.0, 0.0], [0.6, 0.8, 0.0], [0.0, 0.6, 0.8], [-0.8, 0.0, 0.6]])
    transport.glossy_transport(VertexScene.from_arrays(arrays, glossy, recorder), every[::4],
                               sphere, transfer, 4, rng)  # sg.fit's and sg.probe's rays
    # a source at an azimuth no turn of its circle sets in the box's vertical faces'
    # planes (a ray in a face's plane has no well-defined distance)
    rows, weights, _ = source_rings.ring_rows(np.array([0.5, 0.7, 0.3]) / np.sqrt(0.83),
                                              1.0 / 0.3 ** 2, 1.0)
    source_rings.seen_by(vertex_scene, every[::2], rows, weights)  # sg.source_visibility's
    assert_same_hits(recorder, vertex_scene.positions, vertex_scene.faces)


def test_sg_stages_on_the_device_are_reproducible_and_keyed_apart(tmp_path):
    """sg.diffuse, sg.visibility and sg.fit (its transport's rays) baked twice by the
    device: the same bytes, one key each, not Embree's."""
    from tiny_scenes import tiny_scene

    stages = ("sg.diffuse", "sg.visibility", "sg.fit")
    arrays = {}
    for name, device in (("embree", "embree"), ("device", "device"), ("again", "device")):
        scene = tiny_scene(tmp_path / name, "sg").with_settings({"bake.device": device})
        workdir = Workdir(tmp_path / name / "work")
        run(scene, STAGEFILE, workdir, until=stages, progress=False)
        arrays[name] = {stage: open_artifact(workdir.artifact(stage)) for stage in stages}
    for stage, names in (("sg.diffuse", ("transfer",)), ("sg.visibility", ("maps", "occluder")),
                         ("sg.fit", ("lobes", "count", "error"))):
        embree, device, again = (arrays[k][stage] for k in ("embree", "device", "again"))
        for name in names:
            assert np.array_equal(device.read(name), again.read(name)), (stage, name)
        assert device.record["key"] == again.record["key"] != embree.record["key"]
