"""Stage sg.probe: the tabulated glossy transport of the vertices a user asks for."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene
from test_sg import sg_lights_map

from pipeline import job
from pipeline.engine.runner import run
from pipeline.engine.store import Workdir, open_artifact
from pipeline.errors import PrtError
from pipeline.images import write_exr
from pipeline.math.brdf import BrdfParams, glossy, to_local
from pipeline.math.frames import tangent_from_normal
from pipeline.methods.sg.stages.probe import probe_vertices
from pipeline.methods.sg.transport import view_directions
from pipeline.scene.file import load_scene


def bake_probe(tmp_path, vertices):
    write_exr(tmp_path / "env.exr", sg_lights_map().astype(np.float32))
    doc = small_scene_dict(8)
    doc["objects"]["ball"]["primitive"]["subdivisions"] = 1
    doc["lights"] = [{"type": "environment", "file": str(tmp_path / "env.exr")}]
    # direct glossy only (deterministic): the indirect part is sg_transport's, tested there
    doc["settings"] = {"sg.fit_grid": [17, 32], "sg.indirect_samples": 0,
                       "sg.diffuse_samples": 64, "sg.probe_vertices": vertices}
    scene = load_scene(write_scene(tmp_path, doc))
    work = Workdir(tmp_path / "work")
    run(scene, job.stages(), work, until="sg.probe",
        progress=False)
    return scene, open_artifact(work.artifact("sg.probe")), open_artifact(work.artifact("geometry"))


def test_probe_stores_the_direct_glossy_transport_of_the_vertices_asked_for(tmp_path):
    """The ball's most upward vertex (nothing above it) and a floor vertex (Lambert):
    the stored T equals ρs · f_glossy(ω_s, ω_k) · cos θ_s, evaluated here from brdf.py
    for every unoccluded direction of the upper hemisphere (visibility: directions
    within 60° of the normal are open sky for the ball's top vertex), 0 below the
    vertex's horizon and for views below it, and 0 everywhere on the Lambert floor."""
    # vertex indices need the geometry first: bake it with a placeholder probe, then pick
    _, _, geometry = bake_probe(tmp_path, [0])
    ranges = dict(zip(geometry.attrs["object_names"], geometry.read("object_ranges"),
                      strict=True))
    normals = geometry.read("normals").astype(np.float64)
    a, b = ranges["ball"][:2]
    top = int(a + np.argmax(normals[a:b, 1]))
    floor = int(ranges["floor"][0])
    _, art, geometry = bake_probe(tmp_path, [top, floor])
    values = art.read("values")
    directions, omega = art.read("directions"), art.read("solid_angles")
    views = view_directions()
    assert values.shape == (2, 92, 17 * 32, 3) and values.dtype == np.float32
    np.testing.assert_array_equal(art.read("vertex"), [top, floor])
    np.testing.assert_allclose(omega.sum(), 4 * np.pi, rtol=1e-9)
    np.testing.assert_array_equal(art.read("views"), views)
    assert np.all(values[1] == 0)  # the floor is Lambertian: no glossy transport

    n = normals[top] / np.linalg.norm(normals[top])
    np.testing.assert_allclose(art.read("normal")[0], n)
    t = tangent_from_normal(n[None])[0]
    mat = small_scene_dict()["materials"]["shiny"]
    brdf = BrdfParams(model="blinn_phong", albedo=tuple(mat["albedo"]),
                      specular=(mat["specular"],) * 3, gamma=mat["gamma"])
    li, lo = to_local(directions, n, t), to_local(views, n, t)
    open_sky = directions @ n > np.cos(np.radians(60))
    up_view = lo[:, 2] > 0
    expected = glossy(li[open_sky][None], lo[up_view][:, None], brdf) * li[open_sky, 2]
    stored = values[0][np.ix_(up_view, open_sky)]
    assert open_sky.sum() > 50 and expected.max() > 0
    # float32 storage of a float64 evaluation: 1e-6 relative to the largest value
    rho_s = mat["specular"]
    np.testing.assert_allclose(stored[..., 0], expected * rho_s,
                               atol=1e-6 * expected.max() * rho_s)
    np.testing.assert_array_equal(stored[..., 0], stored[..., 2])  # white ρs
    assert np.all(values[0][~up_view] == 0)
    assert np.all(values[0][:, li[:, 2] <= 0] == 0)


def test_probe_vertices_are_checked():
    """An empty list, too many vertices, or an index outside the geometry: a one-line
    error naming the param."""
    for given, text in (([], "empty"), (list(range(65)), "at most"), ([3, 12], "vertex 12")):
        with pytest.raises(PrtError, match=text) as err:
            probe_vertices({"sg.probe_vertices": given}, 10)
        assert "sg.probe_vertices" in str(err.value)
    np.testing.assert_array_equal(probe_vertices({"sg.probe_vertices": [4, 1]}, 10), [4, 1])
