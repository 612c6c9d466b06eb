"""Environment-map mapping and sampling, Radiance HDR reading, image metrics."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import SHARED_DATA

from pipeline.evaluation import metrics
from pipeline.images import read_hdr
from pipeline.math.envmap import EnvironmentMap, direction_to_uv, uv_to_direction


def test_direction_uv_round_trip_and_axes():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(1000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(uv_to_direction(*direction_to_uv(d)), d, atol=1e-12)
    u, v = direction_to_uv(np.array([[0, 0, 1.0], [1.0, 0, 0], [0, 1.0, 0]]))
    np.testing.assert_allclose(u[:2], [0.5, 0.25])  # map centre along +z, u = 1/4 along +x
    np.testing.assert_allclose(v, [0.5, 0.5, 0.0])  # row 0 is the +y pole


def _spot_map(rotation: float = 0.0) -> EnvironmentMap:
    """A 32 x 17 map, black but for one texel at u = 1/4 on the horizon (map +x)."""
    rgb = np.zeros((17, 32, 3))
    rgb[8, 7:9] = 1.0  # columns 7 and 8 are centred at u = 7.5/32 and 8.5/32 around 1/4
    return EnvironmentMap(rgb, rotation)


def test_radiance_is_found_where_the_map_says_and_rotation_turns_it_about_y():
    assert _spot_map().radiance(np.array([[1.0, 0, 0]]))[0, 0] == pytest.approx(1.0)
    assert _spot_map().radiance(np.array([[-1.0, 0, 0]]))[0, 0] == 0.0
    turned = _spot_map(90.0)  # right-handed about +y: +x goes to -z
    assert turned.radiance(np.array([[0, 0, -1.0]]))[0, 0] == pytest.approx(1.0)
    assert turned.radiance(np.array([[1.0, 0, 0]]))[0, 0] == 0.0


def test_rotation_about_any_axis():
    """Rodrigues' rotation is right-handed (about +x, +y goes to +z), equals rotation_y
    about +y, and a map turned about +x by 90° shows its +x spot still at +x and its
    +y pole's light along +z."""
    from pipeline.math.envmap import rotation_about, rotation_y

    np.testing.assert_allclose(rotation_about((0, 1, 0), 37.0), rotation_y(37.0), atol=1e-15)
    np.testing.assert_allclose(rotation_about((2, 0, 0), 90.0) @ [0, 1, 0], [0, 0, 1],
                               atol=1e-15)
    rgb = np.zeros((17, 32, 3))
    rgb[8, 7:9] = 1.0  # the spot at map +x
    rgb[0] = 2.0  # the +y pole's row
    turned = EnvironmentMap(rgb, 90.0, axis=(1.0, 0.0, 0.0))
    assert turned.radiance(np.array([[1.0, 0, 0]]))[0, 0] == pytest.approx(1.0)
    assert turned.radiance(np.array([[0, 0, 1.0]]))[0, 0] == pytest.approx(2.0)
    assert turned.radiance(np.array([[0, 1.0, 0]]))[0, 0] == pytest.approx(0.0, abs=1e-6)


def test_sampling_density_matches_pdf_and_integrates_to_one():
    env = EnvironmentMap(np.random.default_rng(1).gamma(0.5, size=(16, 32, 3)), 25.0)
    rng = np.random.default_rng(2)
    d, pdf = env.sample(rng.random((20000, 3)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(env.pdf(d), pdf, rtol=1e-9)
    # ∫ pdf dω = 1, estimated with uniform directions (std of the estimate ≈ 0.5 %).
    u = rng.normal(size=(200000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    assert np.mean(env.pdf(u)) * 4 * np.pi == pytest.approx(1.0, abs=0.02)


def test_hdr_reader_decodes_flat_and_run_length_files(tmp_path):
    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 3\n"
    pixels = np.array([[128, 64, 32, 129], [0, 0, 0, 0], [255, 128, 0, 130]] * 2, np.uint8)
    (tmp_path / "flat.hdr").write_bytes(header + pixels.tobytes())
    image = read_hdr(tmp_path / "flat.hdr")
    assert image.shape == (2, 3, 3)
    np.testing.assert_allclose(image[0, 0], np.array([128, 64, 32]) * 2.0 ** (129 - 136))
    np.testing.assert_allclose(image[1, 2], np.array([255, 128, 0]) * 2.0 ** (130 - 136))
    assert np.all(image[:, 1] == 0)
    shared = SHARED_DATA / "envmaps" / "grace_256x128.hdr"  # run-length encoded
    if shared.is_file():
        grace = read_hdr(shared)
        assert grace.shape == (128, 256, 3) and np.isfinite(grace).all() and grace.max() > 1


def test_metrics_on_known_differences():
    rng = np.random.default_rng(3)
    reference = rng.random((8, 8, 3)) + 0.1
    assert metrics.relative_rmse(1.1 * reference, reference) == pytest.approx(0.1)
    assert metrics.psnr(reference, reference) == np.inf
    assert metrics.psnr(reference + 0.01, reference) < 60
    emap = metrics.error_map(1.2 * reference, reference)
    np.testing.assert_allclose(emap, 0.2)
    mask = np.zeros((8, 8), bool)
    mask[:4] = True
    changed = reference.copy()
    changed[4:] *= 2
    assert metrics.relative_rmse(changed, reference, mask) == 0.0
    flip = metrics.hdr_flip(1.1 * reference, reference)
    assert flip is None or 0 < flip < 1
    assert metrics.hdr_flip(reference, reference) in (None, 0.0)


def test_srgb_encode_serves_previews_and_psnr(tmp_path):
    """One sRGB encoding: IEC 61966-2-1 values, clipped to [0, 1] after the exposure; the
    PNG preview stores it rounded to 8 bits and PSNR compares it."""
    from PIL import Image

    from pipeline.images import srgb_encode, write_png

    linear = np.array([[[0.0, 0.0031308, 0.5], [0.18, 1.0, 7.0]]])
    expected = [[[0.0, 0.04045, 0.735357], [0.461356, 1.0, 1.0]]]
    np.testing.assert_allclose(srgb_encode(linear), expected, atol=2e-6)
    np.testing.assert_allclose(srgb_encode(linear, 0.5), srgb_encode(linear * 0.5))
    write_png(tmp_path / "p.png", linear, exposure=0.5)
    stored = np.asarray(Image.open(tmp_path / "p.png"))
    assert np.array_equal(stored, np.round(srgb_encode(linear, 0.5) * 255))
    assert metrics.psnr(linear, linear * 1.01, exposure=0.5) == pytest.approx(
        -10 * np.log10(np.mean((srgb_encode(linear, 0.5) - srgb_encode(linear * 1.01, 0.5))
                               ** 2)))
