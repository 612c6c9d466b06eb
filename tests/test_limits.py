"""Each method's declared limits (pipeline/method.py ``Limit``): every one triggered by a
scene that shows it, silent where it does not apply (the shipped scenes at their own
size), printed as ``warning:`` lines, in ``--json`` and listed by ``prt methods``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import PROJECT, SHARED_DATA, small_scene_dict, write_scene
from test_cli import prt
from tiny_scenes import SETTINGS, sky_map

from pipeline import job
from pipeline.registry import get_method, limit_warnings, registry
from pipeline.scene.file import load_scene

needs_data = pytest.mark.skipif(not (SHARED_DATA / "envmaps").is_dir(),
                                reason=f"the shared data folder {SHARED_DATA} is absent")


def _baked(scene, workdir, method: str, until: str) -> dict:
    """Bake ``until`` for ``scene`` and open ``method``'s artifacts that exist."""
    from pipeline.engine.store import open_artifact

    wd = job.workdir_for(scene, workdir)
    job.bake(scene, wd, until=until, quiet=True)
    graph = job.stages()
    return {s: open_artifact(wd.artifact(s), graph.stages[s].output)
            for s in get_method(method).reads if wd.artifact(s).exists()}


def _names(warnings: list[str]) -> list[str]:
    return [w.split(",")[1].split(":")[0].strip() for w in warnings]


def test_every_method_declares_checkable_limits():
    """d2i, triple and sg each declare limits whose checks resolve; `prt methods`
    lists them, as text and in --json."""
    from pipeline.method import resolve

    for name in ("d2i", "triple", "sg"):
        limits = get_method(name).limits
        assert len(limits) >= 2 and len({limit.name for limit in limits}) == len(limits)
        for limit in limits:
            assert callable(resolve(limit.check)) and limit.what
    listed = json.loads(prt("methods", "--json").stdout)
    assert set(listed["sg"]["limits"]) == {"small-sources", "vertex-spacing",
                                           "visibility-folds"}
    assert "  limit texels-per-pixel: " in prt("methods").stdout
    assert all(not m.limits for n, m in registry().items() if n == "direct")


def test_d2i_coefficients_and_gathers_per_pixel(tmp_path):
    """Fewer than 50 of D's coefficients per pixel warn before the bake, and so do more
    than 2 gathers per pixel (the default 16,384 on a 16² image: 64); 100 coefficients
    and 512 gathers (2 per pixel) do not."""
    doc = small_scene_dict(16)
    doc["methods"], doc["settings"] = ["d2i"], {"gather.count": 512}
    d2i = get_method("d2i")
    assert limit_warnings(d2i, load_scene(write_scene(tmp_path, doc))) == []
    doc["settings"] = {"truncate.d_coefficients": 20, "gather.count": 512}
    (warning,) = limit_warnings(d2i, load_scene(write_scene(tmp_path, doc, "few.yaml")))
    assert warning.startswith("method d2i, coefficients-per-pixel: truncate.d_coefficients 20")
    doc["settings"] = {}
    (warning,) = limit_warnings(d2i, load_scene(write_scene(tmp_path, doc, "many.yaml")))
    assert "gathers-per-pixel: gather.count 16384 is 64.0 per pixel of the 16×16" in warning


def test_d2i_gathers_found_in_an_open_scene(tmp_path):
    """A floor alone under a point light: every gather ray escapes, none is found, and
    the check says the indirect light is missing; the floor, box and ball find theirs."""
    doc = small_scene_dict(8)
    doc["methods"], doc["settings"] = ["d2i"], {"gather.count": 64}  # 1 per pixel
    closed = load_scene(write_scene(tmp_path, doc))
    assert limit_warnings(get_method("d2i"), closed,
                          _baked(closed, tmp_path / "w1", "d2i", "d2i.gather")) == []
    doc["objects"] = {"floor": doc["objects"]["floor"]}
    doc["lights"] = doc["lights"][:1]
    floor = load_scene(write_scene(tmp_path, doc, "floor.yaml"))
    (warning,) = limit_warnings(get_method("d2i"), floor,
                                _baked(floor, tmp_path / "w2", "d2i", "d2i.gather"))
    assert "gathers-found: 0 of 64 gather samples" in warning
    assert "no indirect light at all" in warning


def _triple_doc(tmp_path, size: int) -> dict:
    doc = small_scene_dict(size)
    doc["methods"], doc["settings"] = ["triple"], dict(SETTINGS["triple"])
    doc["lights"] = [{"type": "environment", "file": str(sky_map(tmp_path / "sky.exr"))}]
    return doc


def test_triple_texels_and_padding(tmp_path):
    """The tiny scene's 16-texel cap leaves its objects under 1.5 texels per pixel, the
    ball's atlas mostly padding; a camera moved closer names that cause; one sphere
    filling the view with room for its texture is silent."""
    triple = get_method("triple")
    scene = load_scene(write_scene(tmp_path, _triple_doc(tmp_path, 16)))
    artifacts = _baked(scene, tmp_path / "w", "triple", "triple.atlas")
    assert limit_warnings(triple, scene) == []  # both need the baked atlas
    warnings = limit_warnings(triple, scene, artifacts)
    assert _names(warnings) == ["texels-per-pixel", "atlas-padding"]
    assert "objects.ball:" in warnings[0] and "capped at triple.texture_max 16" in warnings[0]
    assert "objects.ball:" in warnings[1] and "of its" in warnings[1]
    camera = {**scene.document["camera"], "position": [0.0, 0.8, 1.6]}
    (closer, _) = limit_warnings(triple, scene.edited("camera", camera), artifacts)
    assert "the pixels it covered for the camera the atlas was baked for" in closer
    doc = _triple_doc(tmp_path, 32)
    doc["objects"] = {"ball": {"primitive": {"type": "sphere", "radius": 1.2,
                                             "subdivisions": 3}, "material": "grey"}}
    doc["camera"]["look_at"] = [0.0, 0.0, 0.0]
    doc["settings"]["triple.texture_max"] = 1024
    ball = load_scene(write_scene(tmp_path, doc, "ball.yaml"))
    assert limit_warnings(triple, ball, _baked(ball, tmp_path / "w2", "triple",
                                               "triple.atlas")) == []


def _sun_map(path, sun: float, suns: int = 1):
    """A dim sky with ``suns`` suns of ``sun`` × its radiance, each 2 × 2 of 64 × 128
    texels, along one row."""
    from pipeline.images import write_exr

    rgb = np.full((64, 128, 3), 0.2, np.float32)
    for k in range(suns):
        rgb[20:22, 4 + 6 * k:6 + 6 * k] = sun * 0.2
    write_exr(path, rgb)
    return path


@pytest.mark.parametrize("sun, suns, warns", [(1.0, 1, False), (30.0, 1, False),
                                              (20000.0, 1, False), (1500.0, 20, True)])
def test_sg_small_sources(tmp_path, sun, suns, warns):
    """Small suns holding most of the light warn, with the share and the SH cell, where
    none is a source taken apart: twenty of < 5 % each (sg.source_min_share), which with
    the sky about them make 96 % of the light in one cell of order 3. One sun of 94 % is a
    source (its shadow comes from the vertices' view of it, not the SH term): no
    warning; nor for a uniform sky or a weak sun (a third of the light)."""
    doc = small_scene_dict(16)
    doc["methods"], doc["settings"] = ["sg"], dict(SETTINGS["sg"])
    doc["lights"] = [{"type": "environment",
                      "file": str(_sun_map(tmp_path / "m.exr", sun, suns))}]
    warnings = limit_warnings(get_method("sg"), load_scene(write_scene(tmp_path, doc)))
    assert bool(warnings) == warns
    if warns:
        assert "small-sources: m.exr holds 96 %" in warnings[0]
        assert "its sources of 5 % or more leave" in warnings[0]
        assert "one cell of sg.diffuse_order 3" in warnings[0]


@needs_data
def test_sg_small_sources_on_the_shipped_maps():
    """Neither shipped map warns: the studio map of dragon_sg holds 89 % of its light in
    1.6 % of the sphere, but its two lights are sources taken apart, and what they
    leave holds 48 % there; Grace Cathedral's of bunny_sg 55 % (no source)."""
    sg = get_method("sg")
    assert limit_warnings(sg, job.open_scene(PROJECT / "scenes" / "bunny_sg.yaml")) == []
    assert limit_warnings(sg, job.open_scene(PROJECT / "scenes" / "dragon_sg.yaml")) == []


def test_sg_vertex_spacing(tmp_path):
    """The tiny scene's 2-triangle floor spans many pixels even at 16² (sg can show
    no shadow on it), its 162-vertex ball a few: only the floor warns there; at 256² the
    ball's edges span many pixels too."""
    doc = small_scene_dict(16)
    doc["methods"], doc["settings"] = ["sg"], dict(SETTINGS["sg"])
    doc["lights"] = [{"type": "environment", "file": str(sky_map(tmp_path / "sky.exr"))}]
    scene = load_scene(write_scene(tmp_path, doc))
    artifacts = _baked(scene, tmp_path / "w", "sg", "geometry")
    sg = get_method("sg")
    (small,) = limit_warnings(sg, scene, artifacts)
    assert "vertex-spacing: objects.floor: its edges span" in small
    assert "objects.ball" not in small and "objects.box" not in small
    (large,) = limit_warnings(sg, scene.with_image_size(256, 256), artifacts)
    assert "objects.floor:" in large and "objects.ball:" in large


def test_sg_visibility_folds():
    """Two objects of two triangles each (a quad, 5 edges): on the first, vertex 0's
    visibility map escapes everywhere and the others' nowhere, so its 3 edges differ by
    1 and the other 2 by 0: a mean step of 3/5, which warns naming the object and the
    remedy; the second's maps differ by 2/255 on every texel (1 %), which does not.
    Without sg.visibility (the lobes' options) nothing is checked."""
    from pipeline.methods.sg.limits import visibility_folds, visibility_step

    class Artifact:
        def __init__(self, arrays, attrs=None):
            self.arrays, self.attrs = arrays, attrs or {}

        def read(self, name):
            return self.arrays[name]

    quad = np.array([[0, 1, 2], [0, 2, 3]])
    faces = np.concatenate([quad, quad + 4])
    maps = np.zeros((8, 5), np.uint8)  # R = 2: 4 finest texels and the 1 × 1 level
    maps[0] = 255
    maps[4:] = [[10] * 5, [12] * 5, [10] * 5, [12] * 5]
    assert visibility_step(maps, 2, quad) == pytest.approx(3 / 5)
    assert visibility_step(maps, 2, quad + 4) == pytest.approx(2 / 255 * 4 / 5)
    geometry = Artifact({"faces": faces, "face_object": np.array([0, 0, 1, 1])},
                        {"object_names": ["scales", "calm"]})
    scene = None  # not read
    text = visibility_folds(scene, {"sg.visibility_resolution": 2},
                            {"geometry": geometry, "sg.visibility": Artifact({"maps": maps})})
    assert text.startswith("objects.scales: neighbouring vertices' visibility differs by "
                           "60.0 %") and "objects.scales.subdivide: 1" in text
    assert "calm" not in text
    assert visibility_folds(scene, {"sg.visibility_resolution": 2},
                            {"geometry": geometry}) is None


def test_render_prints_limits_and_puts_them_in_json(tmp_path):
    """`prt render` prints each limit that applies as one `warning:` line on stderr
    (once, though checked before the bake and at render time) and lists it in --json's
    warnings."""
    scene = write_scene(tmp_path, _triple_doc(tmp_path, 16))
    result = prt("render", scene, "--out", tmp_path / "f.exr", "--workdir", tmp_path / "w",
                 "-q")
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert [line.split(",")[1].split(":")[0].strip() for line in lines] == \
        ["texels-per-pixel", "atlas-padding"]
    result = prt("render", scene, "--out", tmp_path / "f.exr", "--workdir", tmp_path / "w",
                 "--json", "-q")
    assert result.returncode == 0, result.stderr
    warnings = json.loads(result.stdout.splitlines()[-1])["warnings"]
    assert sum("triple, texels-per-pixel" in w for w in warnings) == 1
