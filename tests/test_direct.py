"""The direct-lighting kernel against the NumPy formula, analytic cases, the Cornell frame."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from helpers import PROJECT, small_scene_dict, write_scene

from pipeline import job
from pipeline.device.raytrace import RayTracer
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.job import render_frame
from pipeline.math.brdf import evaluate_world, scene_brdfs
from pipeline.math.lights import pack_lights, quad_emission, shade_direct
from pipeline.math.sampling import lowbias32, stratified_square
from pipeline.render.shadows import light_visibility
from pipeline.scene.edits import with_material_edits
from pipeline.scene.file import load_scene


def bake_and_render(scene_path, workdir):
    scene = load_scene(scene_path)
    run(scene, job.stages(), workdir, until="gbuffer", progress=False)
    return scene, render_frame(scene, workdir, "direct")


def numpy_direct(scene, workdir):
    """The same frame from the NumPy formulas, with visibility traced the same way."""
    gbuf = open_artifact(workdir.artifact("gbuffer"))
    geo = open_artifact(workdir.artifact("geometry"))
    pos = gbuf.read("position").reshape(-1, 3)
    nrm = gbuf.read("normal").reshape(-1, 3)
    obj = gbuf.read("object_id").reshape(-1)
    tan = gbuf.read("tangent").reshape(-1, 3)
    mat = gbuf.read("material_id").reshape(-1)
    brdfs = scene_brdfs(scene, geo.attrs["material_names"])
    packed = pack_lights([(lt.type, lt.params) for lt in scene.lights],
                         {n: i for i, n in enumerate(geo.attrs["object_names"])})
    hit = np.flatnonzero(mat >= 0)
    diag = float(np.linalg.norm(np.subtract(geo.attrs["bbox_max"], geo.attrs["bbox_min"])))
    vis = light_visibility(RayTracer(geo.read("vertices"), geo.read("faces")), pos[hit],
                           nrm[hit], hit, packed, diag)
    view = pos[hit] - np.asarray(scene.camera.position)
    view /= np.linalg.norm(view, axis=1, keepdims=True)

    def brdf(wi):
        return evaluate_world(wi, -view, nrm[hit], tan[hit], mat[hit], brdfs)

    out = np.zeros_like(pos, dtype=np.float64)
    out[hit] = shade_direct(pos[hit], nrm[hit], hit, brdf, packed, vis)
    out[hit] += quad_emission(obj[hit], view, packed)
    return out.reshape(gbuf.read("position").shape), vis


def test_kernel_matches_numpy_all_light_types(tmp_path):
    """Point, spot, directional and quad lights with shadows: kernel = NumPy to 1e-5.

    Tolerance: the kernel works in float32, NumPy in float64; per pixel the sum of a few
    dozen float32 terms differs by a few ulp (~1e-7 relative), so 1e-5 relative (plus
    1e-6 of the image maximum for near-black pixels) leaves margin without hiding bugs."""
    doc = small_scene_dict(size=40)
    doc["lights"] += [
        {"type": "spot", "position": [0.0, 2.0, 0.5], "direction": [0.1, -1.0, 0.0],
         "intensity": [5.0, 4.0, 3.0], "angle": 35, "falloff": 0.3},
        {"type": "directional", "direction": [0.4, -1.0, -0.3], "irradiance": [0.5, 0.6, 0.7]},
    ]
    doc["lights"][1]["samples"] = 9
    scene, frame = bake_and_render(write_scene(tmp_path, doc), Workdir(tmp_path / "w"))
    expected, vis = numpy_direct(scene, Workdir(tmp_path / "w"))
    assert 0.05 < vis.mean() < 0.95  # shadows are present, and light is
    err = np.abs(frame.rgb - expected)
    assert np.all(err <= 1e-5 * np.abs(expected) + 1e-6 * expected.max())
    assert expected.max() > 0.1
    # one kernel: kernel_bytes are its bytes, counted_kernel_ms its time
    assert frame.timings["counted_kernel_ms"] == frame.timings["kernel_ms"] > 0
    assert frame.kernel_bytes > frame.rgb.nbytes


def test_point_light_on_plane_is_analytic(tmp_path):
    """Lambertian plane, point light at height h above pixel: L = a/π · I · cosθ / r²."""
    doc = copy.deepcopy(small_scene_dict(size=16))
    doc["objects"] = {"floor": doc["objects"]["floor"]}
    doc["lights"] = [{"type": "point", "position": [0.0, 1.0, 0.0], "intensity": [2, 3, 4]}]
    scene, frame = bake_and_render(write_scene(tmp_path, doc), Workdir(tmp_path / "w"))
    gbuf = open_artifact(Workdir(tmp_path / "w").artifact("gbuffer"))
    pos, hit = gbuf.read("position"), gbuf.read("object_id") >= 0
    assert hit.mean() > 0.3
    d = np.array([0.0, 1.0, 0.0]) - pos
    r2 = np.sum(d * d, axis=-1)
    cos = d[..., 1] / np.sqrt(r2)
    expected = 0.6 / np.pi * np.array([2, 3, 4]) * (hit * cos / r2)[..., None]
    np.testing.assert_allclose(frame.rgb, expected, rtol=1e-5)


def test_small_quad_light_converges_to_point_light(tmp_path):
    """A small quad of area A and radiance Le acts like a point light of intensity
    Le·A·cosθ_l (a Lambertian emitter): within 1% at distance 20× the quad's size."""
    doc = copy.deepcopy(small_scene_dict(size=8))
    doc["objects"] = {"floor": doc["objects"]["floor"]}
    doc["camera"]["look_at"] = [0.0, 0.0, 0.0]
    s = 0.05
    doc["lights"] = [{"type": "quad", "corner": [-s / 2, 1.0, -s / 2], "edge_u": [s, 0, 0],
                      "edge_v": [0, 0, s], "radiance": [1.0, 1.0, 1.0], "samples": 16}]
    quad_scene, quad_frame = bake_and_render(write_scene(tmp_path, doc), Workdir(tmp_path / "w"))
    doc["lights"] = [{"type": "point", "position": [0.0, 1.0, 0.0],
                      "intensity": [s * s] * 3}]
    point_scene, point_frame = bake_and_render(write_scene(tmp_path, doc, "p.yaml"),
                                               Workdir(tmp_path / "w"))
    pos = open_artifact(Workdir(tmp_path / "w").artifact("gbuffer")).read("position")
    to_light = np.array([0.0, 1.0, 0.0]) - pos
    cos_l = to_light[..., 1:2] / np.linalg.norm(to_light, axis=-1, keepdims=True)
    assert point_frame.rgb.max() > 0
    np.testing.assert_allclose(quad_frame.rgb, point_frame.rgb * cos_l, rtol=1e-2)


def _lowbias32_scalar(x: int) -> int:
    """Wellons' lowbias32 with Python integers (an independent scalar implementation)."""
    m = 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & m
    x ^= x >> 15
    x = (x * 0x846CA68B) & m
    return x ^ (x >> 16)


def test_sampling_hash_and_strata():
    """The vectorised hash equals a scalar one; each stratified sample lies in its cell."""
    xs = [0, 1, 2, 12345, 0x7FFFFFFF, 0xFFFFFFFF]
    assert lowbias32(np.array(xs, np.uint32)).tolist() == [_lowbias32_scalar(x) for x in xs]
    pts = stratified_square(np.arange(5000), 3, 16)
    cells = np.floor(pts * 4).astype(int)
    assert (cells[..., 0] + 4 * cells[..., 1] == np.arange(16)).all()
    assert abs(pts.mean() - 0.5) < 0.01


@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cornell")
    scene = load_scene(PROJECT / "scenes" / "cornell_box.yaml").with_image_size(64, 64)
    workdir = Workdir(tmp / "w")
    run(scene, job.stages(), workdir, until="gbuffer", progress=False)
    return scene, workdir, render_frame(scene, workdir, "direct")


def test_cornell_direct_has_no_colour_bleeding(cornell):
    """Direct light only: every lit white Lambertian surface has the chromaticity of
    light × white albedo (red and green walls cannot tint it), and the luminaire shows
    its radiance."""
    scene, workdir, frame = cornell
    gbuf = open_artifact(workdir.artifact("gbuffer"))
    names = open_artifact(workdir.artifact("geometry")).attrs["object_names"]
    obj = gbuf.read("object_id")
    le = np.array(scene.lights[0].params["radiance"])
    white = np.array(scene.materials["white"].albedo)
    lit = np.isin(obj, [names.index(n) for n in ("back", "ceiling")]) & \
        (frame.rgb.sum(-1) > 1e-3)
    ratio = frame.rgb[lit] / (le * white)
    np.testing.assert_allclose(ratio / ratio[:, :1], 1.0, rtol=1e-4)
    lum = obj == names.index("luminaire")
    assert lum.sum() > 4
    np.testing.assert_allclose(frame.rgb[lum], np.broadcast_to(le, frame.rgb[lum].shape),
                               rtol=1e-6)


def test_cornell_boxes_cast_shadows(cornell):
    """Floor pixels next to each box, on the side away from the light, are darker than
    open floor at the same depth; both boxes cast a shadow."""
    scene, workdir, frame = cornell
    gbuf = open_artifact(workdir.artifact("gbuffer"))
    names = open_artifact(workdir.artifact("geometry")).attrs["object_names"]
    obj, pos = gbuf.read("object_id"), gbuf.read("position")
    floor = obj == names.index("floor")
    lum = frame.rgb.sum(-1)
    # Shadowed floor points are those whose straight path to the light centre is blocked.
    geo = open_artifact(workdir.artifact("geometry"))
    tracer = RayTracer(geo.read("vertices"), geo.read("faces"))
    centre = np.array([278.0, 548.3, 279.5])
    p = pos[floor] + np.array([0, 0.05, 0])
    d = centre - p
    dist = np.linalg.norm(d, axis=1)
    blocked = tracer.occluded(p.astype(np.float32), (d / dist[:, None]).astype(np.float32),
                              (dist * 0.999).astype(np.float32))
    assert blocked.sum() > 20
    assert np.median(lum[floor][blocked]) < 0.5 * np.median(lum[floor][~blocked])
    # Which box blocks each shadowed point: both boxes shadow part of the floor.
    hits = tracer.intersect(p[blocked].astype(np.float32),
                            (d[blocked] / dist[blocked, None]).astype(np.float32))
    owners = {names[i] for i in geo.read("face_object")[hits.prim[hits.prim >= 0]]}
    assert {"largebox", "smallbox"} <= owners


def test_cornell_floor_shows_its_glossy_highlight(cornell):
    """The glossy Blinn-Phong floor reflects the luminaire: against the same frame with
    ρs = 0, the floor gains light only (never loses it), and the gain is largest at the
    front of the floor, nearest the mirror direction (the light's mirror image lies in
    front of the box, out of view)."""
    scene, workdir, frame = cornell
    matte = with_material_edits(scene, ["glossy_floor.specular=0,0,0"])
    assert matte.materials["glossy_floor"].params["specular"] == [0, 0, 0]
    matte_frame = render_frame(matte, workdir, "direct")
    names = open_artifact(workdir.artifact("geometry")).attrs["object_names"]
    floor = open_artifact(workdir.artifact("gbuffer")).read("object_id") == \
        names.index("floor")
    gain = (frame.rgb - matte_frame.rgb).sum(-1)
    assert np.all(gain[floor] >= -1e-6 * frame.rgb.max())
    rows = np.flatnonzero(floor.any(axis=1))
    front, back = rows[-4:], rows[:4]

    def mean_gain(r):
        sel = floor[r]
        return gain[r][sel].mean() / matte_frame.rgb.sum(-1)[r][sel].mean()

    assert mean_gain(front) > 0.2  # measured 0.26 at 64 × 64
    assert mean_gain(front) > 10 * mean_gain(back)  # measured 0.001 at the back


def test_light_row_layout_is_one_table_for_python_and_opencl():
    """The row layout lives in LightRow only: its fields tile the used part of a row
    without overlap (CORNER and EDGE_U are aliases), pack_lights writes each field where
    LightRow says, and kernels/lights.h and direct.cl index rows only through the
    LIGHT_* defines that light_defines() passes to the build (no literal offsets)."""
    import math
    import re

    from pipeline.device import cl
    from pipeline.errors import PrtError
    from pipeline.math.lights import (
        LIGHT_FLOATS,
        TYPE_CODES,
        LightRow,
        light_defines,
        light_fields,
    )

    fields = light_fields()
    aliases = {"CORNER": "POSITION", "EDGE_U": "DIRECTION"}
    assert all(fields[a] == fields[b] for a, b in aliases.items())
    used = np.zeros(LIGHT_FLOATS, int)
    for name, (offset, width) in fields.items():
        if name not in aliases:
            used[offset:offset + width] += 1
    assert used.max() == 1 and used[:18].min() == 1

    row = pack_lights([("spot", {"position": [1, 2, 3], "direction": [0, 0, -2],
                                 "intensity": [4, 5, 6], "angle": 30, "falloff": 0.5}),
                       ("quad", {"corner": [0, 1, 0], "edge_u": [1, 0, 0],
                                 "edge_v": [0, 0, 1], "radiance": [7, 8, 9], "samples": 4,
                                 "object": "lamp"})], {"lamp": 5})
    spot, quad = row.astype(np.float64)
    assert spot[LightRow.TYPE] == TYPE_CODES["spot"] and quad[LightRow.TYPE] == 3
    assert spot[LightRow.POSITION].tolist() == [1, 2, 3]
    assert spot[LightRow.DIRECTION].tolist() == [0, 0, -1]
    assert spot[LightRow.RGB].tolist() == [4, 5, 6]
    assert spot[LightRow.COS_OUTER] == pytest.approx(math.cos(math.radians(30)))
    assert spot[LightRow.COS_INNER] == pytest.approx(math.cos(math.radians(15)))
    assert spot[LightRow.OBJECT] == -1 and quad[LightRow.OBJECT] == 5
    assert quad[LightRow.EDGE_V].tolist() == [0, 0, 1]
    assert (spot[LightRow.SAMPLES], quad[LightRow.SAMPLES]) == (1, 4)
    assert (spot[LightRow.SAMPLE_OFFSET], quad[LightRow.SAMPLE_OFFSET]) == (0, 1)

    defines = light_defines()
    for name in ("lights.h", "direct.cl"):
        source = (cl.kernel_dir() / name).read_text()
        code = re.sub(r"/\*.*?\*/", "", source, flags=re.S)
        assert not re.search(r"row\[\s*\d", code), name
        assert not re.search(r"light_vec\([^,]+,\s*\d", code), name
        assert set(re.findall(r"\bLIGHT_[A-Z_]+\b", code)) <= set(defines), name
    with pytest.raises(PrtError, match="light_defines"):
        cl.program("direct.cl")
