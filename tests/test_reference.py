"""The Monte-Carlo reference renderer: unbiased on scenes with analytic answers, honest
about its own error, deterministic.

Statistical checks use the renderer's own per-pixel variance of the mean, σ²: over the
pixels, z = (I − exact)/σ must average near 0 and z² near 1. With a few hundred pixels
the mean of z² has a standard deviation of about √(2/N) ≈ 0.07, so the accepted band
[0.7, 1.4] fails a biased or a dishonest estimator but not a correct one by chance
(seeds are fixed, so each test's outcome is deterministic anyway).

The stopping estimate covers the surface pixels, not those whose camera ray sees a light
(the Cornell luminaire, an environment's background): see pipeline/evaluation/reference.py.
Radiance is in W/(m² sr); errors and tolerances are relative RMSEs (fractions).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import PROJECT, constant_environment, scene_geometry

from pipeline import job
from pipeline.evaluation.metrics import relative_rmse
from pipeline.evaluation.reference import ReferenceSettings, relative_rmse_estimate, render
from pipeline.math.camera import camera_rays


def _camera(position, look_at, size, fov=40.0):
    return {"position": position, "look_at": look_at, "up": [0, 1, 0], "fov": fov,
            "width": size, "height": size}


def _z_scores(image, exact, variance, mask):
    sigma = np.sqrt(variance[mask])
    z = (image[mask] - exact[mask]) / sigma
    return float(z.mean()), float((z * z).mean())


def test_convex_lambertian_object_under_uniform_environment_shows_albedo_times_radiance(
        tmp_path):
    albedo, radiance = np.array([0.5, 0.25, 0.8]), np.array([0.8, 1.0, 1.2])
    doc = {"format": "prt-scene/1", "name": "furnace",
           "camera": _camera([0, 0, 4], [0, 0, 0], 24),
           "materials": {"m": {"model": "lambert", "albedo": albedo.tolist()}},
           "objects": {"ball": {"primitive": {"type": "sphere", "radius": 1,
                                              "subdivisions": 3}, "material": "m"}},
           "lights": [{"type": "environment",
                       "file": str(constant_environment(tmp_path / "sky.exr",
                                                        radiance.tolist()))}]}
    scene, geometry = scene_geometry(tmp_path, doc)
    for transport in ("env-direct", "full"):
        image = render(scene, geometry, ReferenceSettings(transport, tolerance=0,
                                                          max_spp=64))
        # Pixels whose centre ray meets a sphere of 0.95 (inside the icosphere's faces).
        o, d = camera_rays([0, 0, 4], [0, 0, 0], [0, 1, 0], 40.0, 24, 24)
        b = np.sum(o * d, -1)
        sphere = b * b - (np.sum(o * o, -1) - 0.95 ** 2) > 0
        assert sphere.sum() > 100
        exact = np.broadcast_to(albedo * radiance, image.mean.shape)
        z_mean, z2 = _z_scores(image.mean, exact, image.variance, sphere)
        assert abs(z_mean) < 0.2 and 0.7 < z2 < 1.4, (transport, z_mean, z2)
        rel = image.mean[sphere].mean(0) / (albedo * radiance)
        np.testing.assert_allclose(rel, 1.0, atol=0.005)
        np.testing.assert_allclose(image.mean[0, 0], radiance, rtol=1e-6)  # background
        # The background shows the environment directly: left out of the estimate.
        assert image.emitter_pixels[0, 0] and not image.emitter_pixels[sphere].any()
        assert image.estimate == pytest.approx(relative_rmse_estimate(  # float32 image
            image.mean, image.variance, ~image.emitter_pixels), rel=1e-6)
        assert image.estimate > 1.5 * image.history[-1][3]  # the exact background hid it


def test_closed_emitting_lambertian_enclosure_shows_le_over_one_minus_albedo(tmp_path):
    albedo, emitted = np.array([0.5, 0.3, 0.7]), np.array([1.0, 2.0, 0.5])
    doc = {"format": "prt-scene/1", "name": "enclosure",
           "camera": _camera([0.2, -0.1, 0.3], [1, 0.5, -1], 20, fov=70),
           "materials": {"m": {"model": "lambert", "albedo": albedo.tolist()}},
           "objects": {"room": {"primitive": {"type": "box", "size": [2, 2, 2]},
                                "material": "m"}}}
    scene, geometry = scene_geometry(tmp_path, doc)
    image = render(scene, geometry, ReferenceSettings("full", tolerance=0, max_spp=256),
                   emission={"room": emitted.tolist()})
    exact = np.broadcast_to(emitted / (1.0 - albedo), image.mean.shape)
    everywhere = np.ones(image.mean.shape[:2], bool)
    z_mean, z2 = _z_scores(image.mean, exact, image.variance, everywhere)
    assert abs(z_mean) < 0.2 and 0.7 < z2 < 1.4, (z_mean, z2)
    np.testing.assert_allclose(image.mean.mean((0, 1)), emitted / (1.0 - albedo), rtol=0.005)
    # Every pixel sees the emitting room: the estimate falls back to the whole image.
    assert image.emitter_pixels.all()
    assert image.estimate == image.history[-1][3]
    assert image.estimate == pytest.approx(relative_rmse_estimate(image.mean, image.variance),
                                           rel=1e-6)  # the image is stored as float32


def test_point_light_on_a_lambertian_plane_matches_the_inverse_square_law(tmp_path):
    albedo, intensity, light = 0.6, np.array([3.0, 2.0, 1.0]), np.array([0.3, 1.5, 0.2])
    cam = _camera([0, 2.5, 2.5], [0, 0, 0], 16)
    doc = {"format": "prt-scene/1", "name": "lamp", "camera": cam,
           "materials": {"m": {"model": "lambert", "albedo": [albedo] * 3}},
           "objects": {"floor": {"primitive": {"type": "plane", "size": [40, 40]},
                                 "material": "m"}},
           "lights": [{"type": "point", "position": light.tolist(),
                       "intensity": intensity.tolist()}]}
    scene, geometry = scene_geometry(tmp_path, doc)
    image = render(scene, geometry, ReferenceSettings("direct", tolerance=0, max_spp=2))
    o, d = camera_rays(cam["position"], cam["look_at"], cam["up"], cam["fov"], 16, 16)
    x = o + (-o[..., 1] / d[..., 1])[..., None] * d
    to_light = light - x
    r2 = np.sum(to_light ** 2, -1)
    exact = albedo / np.pi * intensity * (to_light[..., 1] / np.sqrt(r2) / r2)[..., None]
    np.testing.assert_allclose(image.mean, exact, rtol=1e-4)
    assert np.all(image.variance == 0)  # one deterministic connection per pixel


def _polygon_irradiance(points: np.ndarray, normal: np.ndarray, corners: np.ndarray):
    """Irradiance per unit radiance from a polygon (Lambert's formula), unoccluded."""
    total = np.zeros(len(points))
    for i in range(len(corners)):
        a = corners[i] - points
        b = corners[(i + 1) % len(corners)] - points
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        cross = np.cross(a, b)
        angle = np.arccos(np.clip(np.sum(a * b, -1), -1, 1))
        total += angle * (cross @ normal) / np.linalg.norm(cross, axis=-1)
    return np.abs(total) / 2.0


def test_quad_light_with_emitter_geometry_matches_lamberts_polygon_formula(tmp_path):
    """Light sampling and BRDF sampling of the luminaire, combined by MIS, converge to
    the closed-form irradiance of a rectangle."""
    albedo, radiance = 0.7, np.array([4.0, 3.0, 2.0])
    corner, eu, ev = np.array([-0.25, 1.0, -0.25]), np.array([0.5, 0, 0.0]), \
        np.array([0.0, 0, 0.5])  # eu × ev = −y: emits downwards
    cam = _camera([0, 0.6, 2.5], [0, 0, 0], 20)
    doc = {"format": "prt-scene/1", "name": "panel", "camera": cam,
           "materials": {"m": {"model": "lambert", "albedo": [albedo] * 3}},
           "objects": {
               "floor": {"primitive": {"type": "plane", "size": [40, 40]}, "material": "m"},
               "panel": {"primitive": {"type": "plane", "size": [0.5, 0.5]},
                         "transform": {"translate": [0, 1, 0]}, "material": "m"}},
           "lights": [{"type": "quad", "corner": corner.tolist(), "edge_u": eu.tolist(),
                       "edge_v": ev.tolist(), "radiance": radiance.tolist(),
                       "object": "panel"}]}
    scene, geometry = scene_geometry(tmp_path, doc)
    image = render(scene, geometry, ReferenceSettings("direct", tolerance=0, max_spp=256))
    o, d = camera_rays(cam["position"], cam["look_at"], cam["up"], cam["fov"], 20, 20)
    x = (o + (-o[..., 1] / d[..., 1])[..., None] * d).reshape(-1, 3)
    corners = np.array([corner, corner + eu, corner + eu + ev, corner + ev])
    e = _polygon_irradiance(x, np.array([0.0, 1.0, 0.0]), corners)
    exact = (albedo / np.pi * e[:, None] * radiance).reshape(image.mean.shape)
    floor = (d[..., 1] < -0.01) & (image.variance[..., 0] > 0)  # rays that meet the floor
    assert floor.sum() > 250
    z_mean, z2 = _z_scores(image.mean, exact, image.variance, floor)
    assert abs(z_mean) < 0.2 and 0.7 < z2 < 1.4, (z_mean, z2)
    assert relative_rmse(image.mean, exact, floor) < 0.02


@pytest.fixture(scope="module")
def small_cornell(tmp_path_factory):
    scene = job.open_scene(PROJECT / "scenes" / "cornell_box_lambert.yaml", (20, 20))
    folder = tmp_path_factory.mktemp("cornell")
    geometry, _ = job.load_geometry(scene, job.workdir_for(scene, folder))
    return scene, geometry


def test_convergence_estimate_is_within_a_factor_1_5_of_the_measured_error(small_cornell):
    """At a fixed sample count the estimate (over the surface pixels) agrees with the
    error measured there against a render with 16× the paths, whose own error, 1/4 of
    the first's, adds only √(1 + 1/16) ≈ 1.03 to the measured one; 1.5 leaves room for
    the spread of a sum dominated by a few hundred noisy pixels."""
    scene, geometry = small_cornell
    for transport, spp in (("full", 32), ("direct", 8)):
        image = render(scene, geometry, ReferenceSettings(transport, tolerance=0,
                                                          max_spp=spp, seed=1))
        better = render(scene, geometry, ReferenceSettings(transport, tolerance=0,
                                                           max_spp=16 * spp, seed=2))
        measured = relative_rmse(image.mean, better.mean, ~image.emitter_pixels)
        assert 1 / 1.5 < image.estimate / measured < 1.5, (transport, image.estimate,
                                                            measured)


# A tolerance in the spirit of the default 0.01 that this test can afford: at 20x20 the
# surfaces' error is ≈ 0.6/√spp (full transport), so 0.05 stops near 150 spp and the 16×
# longer truth takes ≈ 2.5k spp (about 10 s); 0.01 would take 4k and 60k spp.
STOP_TOLERANCE = 0.05
STOP_PASS_SPP = 8  # small passes, so that the history shows where each estimate crossed


@pytest.fixture(scope="module")
def stopped_cornell(small_cornell):
    """The Lambertian Cornell box at 20x20 (full transport, pixel centres) rendered until
    its estimate is ≤ STOP_TOLERANCE, and a render with 16× its paths (another seed)
    as the truth: (scene, geometry, stopped image, truth)."""
    scene, geometry = small_cornell
    image = render(scene, geometry, ReferenceSettings(
        "full", tolerance=STOP_TOLERANCE, max_spp=4096, spp_per_pass=STOP_PASS_SPP, seed=1))
    truth = render(scene, geometry, ReferenceSettings(
        "full", tolerance=0, max_spp=16 * image.spp, seed=2))
    return scene, geometry, image, truth


def test_progressive_rendering_stops_at_the_tolerance(stopped_cornell):
    _, _, image, _ = stopped_cornell
    assert image.estimate <= STOP_TOLERANCE and image.spp < 4096
    assert image.history[-2][1] > STOP_TOLERANCE  # the pass before had not reached it yet
    assert image.spp == image.history[-1][0]
    assert image.estimate == image.history[-1][1]


def test_stopping_estimate_is_honest_about_the_surfaces(stopped_cornell):
    """The luminaire's pixels (radiance 18.4 in red against < 2 on the surfaces) are
    exactly the ones left out, and the surfaces' error measured against the truth agrees
    with the estimate the render stopped on. The truth's own noise is taken out in
    quadrature (its estimate there, ≈ 1/4 of the stopped image's since it has 16× the
    paths: it would add √(1 + 1/16) ≈ 1.03 to the measured error); the remaining error
    must lie within a factor 1.25 of the estimate. Seeds 1, 3 and 5 give ratios 1.00,
    1.02 and 1.04 (a sum over 1.2k pixel channels, and the stopping rule stops on an
    estimate that has just dipped below the tolerance); the whole-image estimate was
    13× too low here (0.0037 against 0.050). So the image's real surface error is at
    most 1.25 × STOP_TOLERANCE."""
    _, _, image, truth = stopped_cornell
    emitter = image.emitter_pixels
    bright = image.mean[..., 0] > 10
    assert emitter.any() and np.array_equal(emitter, bright)
    surfaces = ~emitter
    truth_noise = relative_rmse_estimate(truth.mean, truth.variance, surfaces)
    assert 0.15 < truth_noise / image.estimate < 0.4  # ≈ 1/√16, a different seed
    measured = relative_rmse(image.mean, truth.mean, surfaces)
    error = math.sqrt(max(measured ** 2 - truth_noise ** 2, 0.0))
    assert 1 / 1.25 < error / image.estimate < 1.25, (image.estimate, error, measured)
    assert error < 1.25 * STOP_TOLERANCE


def test_the_whole_image_estimate_would_have_stopped_far_too_early(stopped_cornell):
    """The bug this estimate fixes: over the whole image, the luminaire's Σ mean² fills
    the norm, so the whole-image estimate (kept in the history) fell below the tolerance
    at the minimum sample count (0.011 at 16 spp), where the surfaces were still ≈ 3×
    the tolerance off (error ≈ 0.6/√16; measured 0.155). The render (152 spp) must go on
    at least 4× longer than that, and the image
    at that point (same seed and passes: the same paths) must measure more than twice
    the tolerance against the truth while its whole-image estimate said it was done."""
    scene, geometry, image, truth = stopped_cornell
    settings = ReferenceSettings("full", tolerance=STOP_TOLERANCE, max_spp=4096,
                                 spp_per_pass=STOP_PASS_SPP, seed=1)
    old_stop = next(spp for spp, _, _, whole in image.history
                    if spp >= settings.min_spp and whole <= STOP_TOLERANCE)
    assert image.spp >= 4 * old_stop, (image.spp, old_stop)
    early = render(scene, geometry, ReferenceSettings(
        "full", tolerance=0, max_spp=old_stop, spp_per_pass=STOP_PASS_SPP, seed=1))
    same = [(spp, estimate, whole) for spp, estimate, _, whole in image.history]
    assert [(spp, e, w) for spp, e, _, w in early.history] == same[:len(early.history)]
    assert early.history[-1][3] <= STOP_TOLERANCE
    surfaces = ~image.emitter_pixels
    assert relative_rmse(early.mean, truth.mean, surfaces) > 2 * STOP_TOLERANCE


def test_a_seed_gives_the_same_image_bit_for_bit(small_cornell):
    scene, geometry = small_cornell
    settings = ReferenceSettings("full", tolerance=0, max_spp=4, seed=7)
    first = render(scene, geometry, settings)
    again = render(scene, geometry, settings)
    other = render(scene, geometry, ReferenceSettings("full", tolerance=0, max_spp=4, seed=8))
    assert np.array_equal(first.mean, again.mean)
    assert np.array_equal(first.variance, again.variance)
    assert not np.array_equal(first.mean, other.mean)


def test_first_glossy_transport_lies_between_direct_and_full_light(small_cornell):
    """first-glossy (d2i's transport) drops glossy reflection after the first vertex: on
    an all-Lambertian scene it equals full transport; it always adds bounce light to
    direct."""
    scene, geometry = small_cornell
    results = {t: render(scene, geometry, ReferenceSettings(t, tolerance=0, max_spp=64,
                                                            seed=3))
               for t in ("direct", "first-glossy", "full")}
    surfaces = ~results["full"].emitter_pixels  # where the estimates apply
    assert relative_rmse(results["first-glossy"].mean, results["full"].mean, surfaces) < 3 * max(
        results["first-glossy"].estimate, results["full"].estimate)
    assert results["first-glossy"].mean.sum() > 1.1 * results["direct"].mean.sum()


def test_first_glossy_indirect_is_first_glossy_less_direct(small_cornell):
    """first-glossy-indirect drops exactly the direct part: direct + it agrees with
    first-glossy within the three images' noise (z-scores over the surface pixels, band
    as in the module docstring), and it carries no light where first-glossy equals direct
    (the luminaire seen from the camera)."""
    scene, geometry = small_cornell
    results = {t: render(scene, geometry, ReferenceSettings(t, tolerance=0, max_spp=64,
                                                            seed=s))
               for s, t in enumerate(("direct", "first-glossy", "first-glossy-indirect"))}
    total = results["direct"].mean + results["first-glossy-indirect"].mean
    variance = sum(r.variance for r in results.values())
    mask = (variance > 0) & np.isfinite(variance)
    z_mean, z_sq = _z_scores(total, results["first-glossy"].mean, variance, mask)
    assert abs(z_mean) < 0.15 and 0.7 < z_sq < 1.4
    indirect = results["first-glossy-indirect"].mean
    assert indirect.max() < 0.2 * results["direct"].mean.max()
    assert indirect.sum() > 0.05 * results["direct"].mean.sum()
    # The luminaire seen from the camera is an emitter pixel only where its light counts.
    assert results["first-glossy"].emitter_pixels.any()
    assert not results["first-glossy-indirect"].emitter_pixels.any()


def test_glossy_and_diffuse_lobes_add_up_to_the_reflected_light(tmp_path):
    """``lobe``: the glossy part of the BRDF at the first surface plus its diffuse part
    is all of it (the Cornell box with its glossy floor, first-glossy transport, z-scores
    of the sum against the whole over the reflecting pixels, band as in the module
    docstring); a lobe's image holds no light seen directly (the luminaire's emission),
    and on Lambertian surfaces the glossy lobe reflects nothing."""
    scene = job.open_scene(PROJECT / "scenes" / "cornell_box.yaml", (16, 16))
    geometry, _ = job.load_geometry(scene, job.workdir_for(scene, tmp_path))
    results = {lobe: render(scene, geometry, ReferenceSettings(
        "first-glossy", tolerance=0, max_spp=64, seed=s, lobe=lobe))
        for s, lobe in enumerate(("all", "glossy", "diffuse"))}
    emitters = results["all"].emitter_pixels
    assert emitters.any() and not results["glossy"].emitter_pixels.any()
    total = results["glossy"].mean + results["diffuse"].mean
    variance = sum(r.variance for r in results.values())
    mask = ~emitters[..., None] & (variance > 0)
    z_mean, z_sq = _z_scores(total, results["all"].mean, variance, mask)
    assert abs(z_mean) < 0.15 and 0.7 < z_sq < 1.4
    # the luminaire's pixels keep the light it reflects, not its emission (≈ 18 vs 0.2)
    assert np.all(total[emitters].sum(-1) < 0.05 * results["all"].mean[emitters].sum(-1))
    glossy = results["glossy"].mean
    floor = glossy.sum(axis=-1) > 0
    assert floor.mean() > 0.1  # the glossy floor: the bottom rows of the frame
    assert np.all(glossy[: scene.camera.height // 3] == 0)  # walls and ceiling: Lambert
