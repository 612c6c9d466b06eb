"""Scene files: the shipped scenes load and look at what they should; transforms; keys."""

from __future__ import annotations

import copy
import shutil

import numpy as np
import pytest
from helpers import PROJECT, SHARED_DATA, small_scene_dict, write_scene

from pipeline.runner import plan, run
from pipeline.scene import load_scene
from pipeline.stagefile import load_stagefile
from pipeline.store import Workdir, open_artifact


def test_cornell_box_scene():
    """The default scene: the eight objects named after the meshes, glossy floor, one quad
    light facing down with Mitsuba's radiance, Mitsuba's camera."""
    scene = load_scene(PROJECT / "scenes" / "cornell_box.yaml")
    assert list(scene.objects) == ["floor", "ceiling", "back", "redwall", "greenwall",
                                   "largebox", "smallbox", "luminaire"]
    assert scene.materials[scene.objects["floor"].material].model == "blinn_phong"
    (light,) = scene.lights
    assert light.type == "quad" and light.params["radiance"] == [18.387, 10.9873, 2.75357]
    normal = np.cross(light.params["edge_u"], light.params["edge_v"])
    assert normal[1] < 0 and np.isclose(np.linalg.norm(normal), 130 * 105)
    assert scene.camera.position == (278.0, 273.0, -800.0) and scene.camera.fov == 39.3077


def test_bunny_grace_scene_sees_bunny_on_ground(tmp_path, monkeypatch):
    """The bunny scene resolves its mesh and map from the shared data folder, and its
    camera sees the bunny standing on the ground plane."""
    monkeypatch.setenv("PRT_DATA", str(SHARED_DATA))
    scene = load_scene(PROJECT / "scenes" / "bunny_grace.yaml").with_image_size(32, 32)
    assert scene.objects["bunny"].mesh == SHARED_DATA / "meshes" / "bunny_60kf.obj"
    assert scene.lights[0].type == "environment"
    workdir = Workdir(tmp_path / "w")
    run(scene, load_stagefile(), workdir, until="gbuffer", progress=False)
    geo = open_artifact(workdir.artifact("geometry"))
    bunny = geo.read("object_ranges")[0]
    assert bunny[3] - bunny[2] == 59664
    ids = open_artifact(workdir.artifact("gbuffer")).read("object_id")
    assert 0.15 < (ids == 0).mean() < 0.7 and (ids == 1).mean() > 0.1
    ground_y = geo.read("vertices")[geo.read("object_ranges")[1][0]][1]
    bunny_y = geo.read("vertices")[bunny[0]:bunny[1], 1]
    assert abs(bunny_y.min() - ground_y) < 1e-3


def test_transform_order_scale_rotate_translate(tmp_path):
    """transform = translate · Rz · Ry · Rx · scale, angles in degrees."""
    doc = small_scene_dict()
    doc["objects"]["box"]["transform"] = {"scale": 2.0, "rotate": [0, 90, 0],
                                          "translate": [1, 2, 3]}
    m = np.array(load_scene(write_scene(tmp_path, doc)).objects["box"].transform)
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [1, 2, 1, 1], atol=1e-12)  # x -> -z
    np.testing.assert_allclose(m @ [0, 1, 0, 1], [1, 4, 3, 1], atol=1e-12)


def test_mesh_section_key_follows_content_not_location(tmp_path):
    """Moving a scene and its mesh elsewhere keeps the section value; editing the mesh
    file changes it."""
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        shutil.copy(PROJECT / "scenes" / "cornell_box" / "cbox_floor.obj", tmp_path / name)
    doc = copy.deepcopy(small_scene_dict())
    doc["objects"]["floor"] = {"mesh": "cbox_floor.obj", "material": "grey"}
    scene_a = load_scene(write_scene(tmp_path / "a", doc))
    scene_b = load_scene(write_scene(tmp_path / "b", doc))
    a, b = scene_a.section("objects.floor"), scene_b.section("objects.floor")
    assert a == b
    # the leaf that stages declare (objects.*.mesh), and so the stage keys, too
    assert scene_a.section("objects.floor.mesh") == scene_b.section("objects.floor.mesh")
    keys = [{p.spec.name: p.key for p in plan(s, load_stagefile(), Workdir(tmp_path / "w"))}
            for s in (scene_a, scene_b)]
    assert keys[0] == keys[1]
    with open(tmp_path / "b" / "cbox_floor.obj", "a") as f:
        f.write("v 1 2 3\n")
    edited = load_scene(tmp_path / "b" / "scene.yaml")
    assert edited.section("objects.floor") != a
    assert edited.section("objects.floor.mesh") != scene_a.section("objects.floor.mesh")


@pytest.mark.parametrize("samples", [3, 0])
def test_quad_samples_must_be_square(tmp_path, samples):
    """Stratified quad sampling needs m² samples; anything else is a clear error."""
    from pipeline.errors import PrtError

    doc = small_scene_dict()
    doc["lights"][1]["samples"] = samples
    with pytest.raises(PrtError, match=r"lights\[1\]\.samples"):
        load_scene(write_scene(tmp_path, doc))
