"""The Mitsuba 3 cross-check for every BRDF model (pipeline/evaluation/mitsuba.py and its
Python BSDFs, pipeline/evaluation/mitsuba_bsdfs.py): each BSDF's values against
pipeline/math/brdf.py (two independent implementations), its sampling against its own
density, our tangent frame on a mesh with uv, and a tiny render of each model in both
renderers agreeing within the noise rule of studies/mitsuba_crosscheck.py.

Skipped where Mitsuba is not installed (the optional ``mitsuba`` extra, not in CI)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.math import brdf

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("mitsuba") is None,
    reason="Mitsuba 3 is not installed (the optional 'mitsuba' extra: "
           "pip install 'prt-pipeline[mitsuba]')")

ROOT = Path(__file__).resolve().parent.parent
MODELS = tuple(brdf.MATERIAL_PARAMETERS)
KD, KS = (0.3, 0.4, 0.5), (0.2, 0.5, 0.7)


@pytest.fixture(scope="module")
def mi():
    from pipeline.evaluation import mitsuba

    return mitsuba._mitsuba()


def _params(model: str) -> brdf.BrdfParams:
    from pipeline.evaluation.mitsuba import CROSSCHECK_PARAMETERS

    p = {k: v for k, v in CROSSCHECK_PARAMETERS[model].items() if k != "specular"}
    return brdf.BrdfParams.from_material(model, KD, {"specular": KS, **p}) \
        if model != "lambert" else brdf.BrdfParams("lambert", KD)


def _bsdf(mi, model: str):
    p = _params(model)
    return mi.load_dict({"type": "prt_brdf", "model": model, "gamma": p.gamma,
                         "alpha_ratio": p.alpha_ratio, "cxy": p.cxy, "cz": p.cz, "f0": p.f0,
                         **{f"kd_{c}": p.albedo[i] for i, c in enumerate("rgb")},
                         **{f"ks_{c}": p.specular[i] for i, c in enumerate("rgb")}})


def _local_si(mi, v: np.ndarray):
    """An interaction with shading normal and face normal +z, viewer ``v`` (N, 3); no
    shape (no uv: the tangent is the Duff et al. one of +z, i.e. +x)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(v))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
    si.wi = mi.Vector3f(v.T)
    return si


def _hemisphere(rng, n: int) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    return d


@pytest.mark.parametrize("model", MODELS)
def test_bsdf_matches_the_brdf_module(mi, model):
    """f · N·L of the Mitsuba BSDF equals pipeline.math.brdf.evaluate · N·L at random
    directions. Tolerance: the BSDF runs in float32, and N·H after normalising L + V
    carries a rounding of ≈ 1e-6 relative; the lobes amplify it by their logarithmic
    slope, d ln f / d(N·H) = γ / (N·H) for cos^γ (γ ≤ 100) and ≈ 2/(α² cos³δ) for the
    Gaussian lobes (α = 0.08…0.2: 50…300, plus 4/cosδ for Beckmann's 1/cos⁴δ), i.e. up to
    ≈ 3e-4 (measured worst: 1.1e-4, Cook-Torrance). 5e-4 relative plus 1e-6 of the peak
    is still far below any formula slip (a wrong constant, a missing cos, L and V
    swapped in an asymmetric term)."""
    rng = np.random.default_rng(7)
    light, view = _hemisphere(rng, 4096), _hemisphere(rng, 4096)
    ours = brdf.evaluate(light, view, _params(model)) * light[:, 2:3]
    theirs = np.asarray(_bsdf(mi, model).eval(mi.BSDFContext(), _local_si(mi, view),
                                              mi.Vector3f(light.T))).T
    np.testing.assert_allclose(theirs, ours, rtol=5e-4, atol=1e-6 * ours.max())
    # below either horizon: nothing
    below = light * [1, 1, -1]
    zero = np.asarray(_bsdf(mi, model).eval(mi.BSDFContext(), _local_si(mi, view),
                                            mi.Vector3f(below.T)))
    assert not zero.any()


@pytest.mark.parametrize("model", MODELS)
def test_bsdf_sampling_is_consistent(mi, model):
    """sample's weight is eval/pdf, its pdf is pdf(), and pdf is the density of what
    sample draws: ∫ pdf dω over the hemisphere (uniform estimate) equals the fraction of
    samples that land above it."""
    rng = np.random.default_rng(3)
    n = 1 << 16
    view = _hemisphere(rng, n)
    bsdf, ctx, si = _bsdf(mi, model), mi.BSDFContext(), _local_si(mi, view)
    bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(n)), mi.Point2f(rng.random((2, n))))
    value, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
    weight, value, pdf, bs_pdf = (np.asarray(a) for a in (weight, value, pdf, bs.pdf))
    np.testing.assert_allclose(bs_pdf, pdf, rtol=1e-6)
    ok = pdf > 0
    np.testing.assert_allclose(weight[:, ok], value[:, ok] / pdf[ok], rtol=1e-5, atol=1e-6)
    landed = ok.mean()
    uniform = _hemisphere(rng, n)
    integral = 2 * np.pi * np.asarray(bsdf.pdf(ctx, si, mi.Vector3f(uniform.T)))
    # the uniform estimate's standard error is large for sharp lobes: compare the means
    # over many viewers, within 4 standard errors
    se = integral.std() / math.sqrt(n)
    assert abs(integral.mean() - landed) < 4 * se + 4 * math.sqrt(landed / n)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_anisotropic_ward_uses_our_tangent(mi, side):
    """On a quad whose uv runs diagonally, the anisotropic Ward BSDF evaluates in our
    frame (pipeline/device/raytrace.py: dP/du made orthogonal to the facing normal),
    seen from either side."""
    from pipeline.evaluation import mitsuba
    from pipeline.math.frames import face_tangents, orthonormalize

    s = math.sqrt(0.5)
    vertices = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float64)
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    # u along (1, 0, 1)/√2, v along (−1, 0, 1)/√2
    uv = np.stack([(vertices[:, 0] + vertices[:, 2]) * s, (vertices[:, 2] - vertices[:, 0]) * s], 1)
    dpdu = face_tangents(vertices, uv, faces)
    bsdf = mi.load_dict(mitsuba.bsdf_dict_from(
        "ward_anisotropic", KD, {"specular": KS, "gamma": 0.2, "alpha_ratio": 4.0}))
    mesh = mitsuba._mesh(mi, "quad", vertices, faces, normals, bsdf, None, dpdu)
    scene = mi.load_dict({"type": "scene", "quad": mesh})
    rng = np.random.default_rng(5)
    n = 2048
    origin_dir = _hemisphere(rng, n)[:, [0, 2, 1]] * [1, side, 1]  # viewer side ±y
    target = np.concatenate([rng.uniform(-0.5, 0.5, (n, 1)), np.zeros((n, 1)),
                             rng.uniform(-0.5, 0.5, (n, 1))], 1)
    origin = target + 2.0 * origin_dir
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(origin.T), mi.Vector3f(-origin_dir.T)))
    assert np.asarray(si.is_valid()).all()
    light = _hemisphere(rng, n)[:, [0, 2, 1]] * [1, side, 1]
    theirs = np.asarray(si.bsdf().eval(mi.BSDFContext(), si, si.to_local(mi.Vector3f(light.T)))).T
    normal = np.array([0.0, side, 0.0])
    tangent = orthonormalize(dpdu[0], normal)
    p = brdf.BrdfParams("ward_anisotropic", KD, KS, 0.2, 4.0)
    lo, vo = brdf.to_local(light, normal, tangent), brdf.to_local(origin_dir, normal, tangent)
    ours = brdf.evaluate(lo, vo, p) * lo[:, 2:3]
    np.testing.assert_allclose(theirs, ours, rtol=5e-4, atol=1e-5 * ours.max())
    # and the frame matters: the tangent along x (the fallback) gives other values
    wrong = brdf.evaluate(brdf.to_local(light, normal, [1.0, 0, 0]),
                          brdf.to_local(origin_dir, normal, [1.0, 0, 0]), p) * lo[:, 2:3]
    assert np.abs(wrong - ours).max() > 0.1 * ours.max()


@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    from pipeline import job

    scene = job.open_scene(ROOT / "scenes" / "cornell_box.yaml").with_image_size(24, 24)
    geometry, _ = job.load_geometry(
        scene, job.workdir_for(scene, tmp_path_factory.mktemp("cornell") / "work"), quiet=True)
    return scene, geometry


@pytest.mark.parametrize("model", MODELS)
def test_renders_agree_within_the_noise(cornell, model):
    """The Cornell box with its floor and boxes of ``model`` (24², 64 paths per pixel,
    transport full): ours and Mitsuba's differ by no more than 3× their combined noise,
    over the image and over the model's pixels (studies/mitsuba_crosscheck.py's rule)."""
    from pipeline.evaluation import mitsuba
    from pipeline.evaluation.reference import ReferenceSettings, render

    scene, geometry = cornell
    scene = mitsuba.with_model(scene, ("glossy_floor", "box"), model)
    spp, runs = 64, 4
    ours = render(scene, geometry, ReferenceSettings(
        "full", tolerance=0.0, max_spp=spp, min_spp=spp, seed=1, pixel_filter="box"))
    frames = np.stack([mitsuba.render(scene, geometry, "full", spp // runs, seed=s).rgb
                       for s in range(runs)]).astype(np.float64)
    theirs, theirs_var = frames.mean(0), frames.var(0, ddof=1) / runs
    ours_mean, ours_var = ours.mean.astype(np.float64), ours.variance.astype(np.float64)
    floor_rows = slice(16, 24)  # the floor and the boxes' feet fill the bottom third
    for sel in (np.s_[:], np.s_[floor_rows]):
        diff = np.linalg.norm(ours_mean[sel] - theirs[sel])
        noise = math.sqrt(float(np.sum(ours_var[sel] + theirs_var[sel])))
        assert diff <= 3 * noise, (model, sel, diff / noise)

