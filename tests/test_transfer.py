"""The d2i transfer estimators (pipeline/methods/d2i/transfer.py) against brute-force
integration over the gather disks (the area measure, with the squared distance that the
paper's pdf drops)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.math.brdf import BrdfParams, coordinate, fixed_term, to_local
from pipeline.math.frames import tangent_from_normal
from pipeline.methods.d2i.brdf_pca import build_basis
from pipeline.methods.d2i.transfer import (
    Disks,
    GlossyTable,
    Receivers,
    disk_pattern,
    disk_polygons,
    polygon_geometry,
    split_near,
    subarea_points,
    transfer,
)

SUBAREA = 256


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _disks(centers, normals, areas, rotation=0.3):
    centers, normals = np.asarray(centers, float), _unit(normals)
    areas = np.asarray(areas, float)
    tangents = tangent_from_normal(normals)
    points = subarea_points(centers, normals, tangents, np.sqrt(areas / np.pi),
                            np.full(len(areas), rotation), disk_pattern(SUBAREA))
    return Disks(centers, normals, areas, points,
                 disk_polygons(centers, normals, tangents, areas))


def _brute_force(receivers, disks, integrand, rings=300, sectors=600):
    """∫_K G(x, q) integrand(ω) dA by the midpoint rule in polar coordinates on each
    disk; (P, G, ...) ."""
    out = []
    for c, n, a in zip(disks.center, disks.normal, disks.area, strict=True):
        r_max = np.sqrt(a / np.pi)
        r = (np.arange(rings) + 0.5) / rings * r_max
        phi = (np.arange(sectors) + 0.5) / sectors * 2 * np.pi
        t = tangent_from_normal(n[None])[0]
        b = np.cross(n, t)
        q = c + (r[:, None, None] * (np.cos(phi)[None, :, None] * t
                                     + np.sin(phi)[None, :, None] * b))
        da = r[:, None] * (r_max / rings) * (2 * np.pi / sectors)
        d = q[None] - receivers.position[:, None, None]
        r2 = np.sum(d * d, -1)
        w = d / np.sqrt(r2)[..., None]
        g = (np.maximum(np.einsum("pijc,pc->pij", w, receivers.normal), 0)
             * np.maximum(-(w @ n), 0) / r2)
        value = integrand(w) * (g * da)[..., None]
        out.append(value.sum(axis=(1, 2)))
    return np.stack(out, axis=1)


def _receivers(positions, normals, eye):
    positions, normals = np.asarray(positions, float), _unit(normals)
    return Receivers(positions, normals, tangent_from_normal(normals),
                     _unit(np.asarray(eye, float) - positions))


@pytest.fixture(scope="module")
def scene():
    # receivers on a floor (y = 0); disks on a wall (z = 1, facing −z) and a ceiling
    receivers = _receivers([[0.0, 0.0, 0.0], [0.3, 0.0, 0.5], [-0.2, 0.0, 0.9]],
                           [[0, 1, 0]] * 3, eye=[0.0, 1.0, -3.0])
    disks = _disks([[0.0, 0.5, 1.0], [0.2, 0.1, 1.0], [0.0, 1.0, 0.4], [0.1, 0.02, 0.98]],
                   [[0, 0, -1], [0, 0, -1], [0, -1, 0], [0, 0, -1]],
                   [0.05, 0.01, 0.2, 0.002])
    return receivers, disks


def test_diffuse_transfer_matches_brute_force_over_the_disk(scene):
    receivers, disks = scene
    vis = np.ones((3, 4))
    d, _ = transfer(receivers, disks, vis, None, solid_angle=1e-9, tolerance=0.0)
    exact = _brute_force(receivers, disks, lambda w: np.ones(w.shape[:-1] + (1,)))[..., 0]
    # 256 Halton points on a smooth integrand: within 2 % (pairs that see the disk
    # edge-on near its plane converge slowest)
    np.testing.assert_allclose(d, exact / np.pi, rtol=0.02, atol=1e-6)


def test_visibility_multiplies_every_entry(scene):
    receivers, disks = scene
    vis = np.array([[1, 0, 1, 0], [0, 1, 1, 1], [1, 1, 0, 1]], float)
    d_all, _ = transfer(receivers, disks, np.ones((3, 4)), None, 1e-9, 0.0)
    d, _ = transfer(receivers, disks, vis, None, 1e-9, 0.0)
    np.testing.assert_array_equal(d, d_all * vis)


@pytest.mark.parametrize("model,gamma_range", [("blinn_phong", (3.0, 300.0)),
                                               ("ward", (0.05, 2.0)),
                                               ("cook_torrance", (0.1, 2.0))])
def test_glossy_transfer_rows_match_brute_force(scene, model, gamma_range):
    receivers, disks = scene
    params = BrdfParams(model, (0.5, 0.5, 0.5), (1.0, 1.0, 1.0), gamma_range[0])
    basis = build_basis(params, gamma_range, 1e-2, 12)
    table = GlossyTable.from_basis(basis)
    _, t = transfer(receivers, disks, np.ones((3, 4)), table, 1e-9, 0.0)

    def rows(w):
        wi = to_local(w, receivers.normal[:, None, None], receivers.tangent[:, None, None])
        wo = np.broadcast_to(to_local(receivers.wo, receivers.normal,
                                      receivers.tangent)[:, None, None], wi.shape)
        x = coordinate(wi, wo, params)
        f = fixed_term(wi, wo, params)
        return np.stack([np.interp(x, table.grid, row) * f for row in table.rows], -1)

    exact = np.moveaxis(_brute_force(receivers, disks, rows), -1, 1)  # (P, R, G)
    # Compare against each receiver's largest entry: basis rows change sign and the
    # higher ones oscillate, so single entries can be near zero, and 256 QMC points on
    # an oscillating integrand err by a few % of that row's own scale (measured: up to
    # 22 % of row 7's for the 0.2 m² disk 0.3 m away), but ≤ 1.2 % of the receiver's.
    scale = np.abs(exact).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(t - exact) <= 0.02 * scale)


def test_the_sum_over_basis_rows_is_the_glossy_brdf_transfer(scene):
    """c(γ)ᵀ T equals the transfer of the reconstructed BRDF f_F (b0 + Σ c_j b_j)."""
    receivers, disks = scene
    params = BrdfParams("blinn_phong", (0, 0, 0), (1, 1, 1), 40.0)
    basis = build_basis(params, (3.0, 300.0), 1e-3, 16)
    table = GlossyTable.from_basis(basis)
    _, t = transfer(receivers, disks, np.ones((3, 4)), table, 1e-9, 0.0)
    c = np.r_[1.0, basis.coefficients(40.0)]
    combined = np.einsum("r,prg->pg", c, t)

    def glossy(w):
        wi = to_local(w, receivers.normal[:, None, None], receivers.tangent[:, None, None])
        wo = np.broadcast_to(to_local(receivers.wo, receivers.normal,
                                      receivers.tangent)[:, None, None], wi.shape)
        x = coordinate(wi, wo, params)
        return (basis.reconstruct(40.0, x, clamp=False) * fixed_term(wi, wo, params))[..., None]

    exact = _brute_force(receivers, disks, glossy)[..., 0]
    assert np.all(np.abs(combined - exact) <= 0.03 * np.abs(exact).max() + 1e-9)


def test_convergence_threshold_uses_fewer_samples_for_far_disks():
    """A far, small disk (Ω ≪ Ω_s) is estimated from one sample, and its value is close
    to the point form factor; a near, large one (0.3 m below a 0.2 m² disk) keeps
    doubling until its halves agree within 1 % and then matches brute force within 2 %
    (measured 0.8 %)."""
    receivers = _receivers([[0, 0, 0]], [[0, 1, 0]], eye=[0, 1, -3])
    far = _disks([[0, 5, 0]], [[0, -1, 0]], [1e-3])
    d_far, _ = transfer(receivers, far, np.ones((1, 1)), None, solid_angle=0.01,
                        tolerance=0.02)
    np.testing.assert_allclose(d_far[0, 0], 1e-3 / 25 / np.pi, rtol=1e-3)
    near = _disks([[0, 0.3, 0.2]], [[0, -1, 0]], [0.2])
    d_near, _ = transfer(receivers, near, np.ones((1, 1)), None, solid_angle=0.01,
                         tolerance=0.01)
    exact = _brute_force(receivers, near, lambda w: np.ones(w.shape[:-1] + (1,)))[0, 0, 0]
    np.testing.assert_allclose(d_near[0, 0], exact / np.pi, rtol=0.02)


@pytest.mark.parametrize("model,gamma_range", [(None, None), ("blinn_phong", (3.0, 300.0)),
                                               ("lafortune", (3.0, 300.0)),
                                               ("ward_anisotropic", (0.05, 2.0)),
                                               ("cook_torrance", (0.1, 2.0)),
                                               ("ashikhmin_shirley", (3.0, 300.0))])
def test_opencl_kernel_matches_numpy(scene, model, gamma_range):
    """kernels/d2i/transfer.cl = pipeline/methods/d2i/transfer.py on float32 inputs, with adaptive
    sample counts and no early stop (tolerance 0: a float32 and a float64
    sum may stop at different prefixes). To 2e-4 of each receiver's largest entry:
    float32 sums of up to 256 terms, and the basis cell found from a float32 angle."""
    from pipeline.methods.d2i.stages.transfer import TransferKernel

    receivers, disks = scene
    receivers = Receivers(*(a.astype(np.float32).astype(float) for a in (
        receivers.position, receivers.normal, receivers.tangent, receivers.wo)))
    disks = Disks(*(a.astype(np.float32).astype(float) for a in (
        disks.center, disks.normal, disks.area, disks.points, disks.polygon)))
    vis = np.array([[1, 1, 1, 0], [1, 1, 1, 1], [0, 1, 1, 1]], np.uint8)
    table = None
    if model is not None:
        params = BrdfParams(model, (0.5, 0.5, 0.5), (1.0, 1.0, 1.0), gamma_range[0],
                            alpha_ratio=0.5, f0=0.1)
        table = GlossyTable.from_basis(build_basis(params, gamma_range, 1e-2, 12))
    # Ω_s = 0.0093: no pair's Ω / Ω_s lies at a power of two, where float32 and float64
    # may round to different sample counts
    d_ref, t_ref = transfer(receivers, disks, vis, table, solid_angle=0.0093, tolerance=0.0)
    d, t = TransferKernel(disks, 0.0093, 0.0)(receivers, vis, table)  # float32 on the device
    scale = np.abs(d_ref).max(axis=1, keepdims=True)
    assert np.all(np.abs(d - d_ref) <= 2e-4 * scale)
    if model is None:
        assert t is None
        return
    scale = np.abs(t_ref).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(t - t_ref) <= 2e-4 * scale)


def test_polygon_geometry_is_exact_for_a_square_cut_by_the_receivers_horizon():
    """Lambert's formula over a square on a wall that reaches below the receiver's floor
    plane, the receiver 2 mm in front of it: against a 2000² midpoint grid on the part
    above the floor (within 0.2 %; the grid resolves the 2 mm peak with 0.05 mm cells)."""
    x, n = np.array([[0.0, 0.0, 0.998]]), np.array([[0.0, 1.0, 0.0]])
    square = np.array([[[-0.05, -0.05, 1.0], [0.05, -0.05, 1.0], [0.05, 0.05, 1.0],
                        [-0.05, 0.05, 1.0]]])
    exact, centroid = polygon_geometry(x, n, square)
    cells = 2000
    u = (np.arange(cells) + 0.5) / cells * 0.1 - 0.05
    v = (np.arange(cells // 2) + 0.5) / (cells // 2) * 0.05  # y ≥ 0 only
    qx, qy = np.meshgrid(u, v, indexing="ij")
    d = np.stack([qx, qy, np.full_like(qx, 1.0)], -1) - x[0]
    r2 = np.sum(d * d, -1)
    g = (d[..., 1] / np.sqrt(r2)) * (d[..., 2] / np.sqrt(r2)) / r2
    brute = g.sum() * (0.1 / cells) * (0.05 / (cells // 2))
    assert exact[0] == pytest.approx(brute, rel=2e-3)
    # the clipped polygon is the upper half: its vertex mean lies above the floor
    assert centroid[0, 1] > 0


def test_diffuse_transfer_is_exact_at_a_contact_where_sampling_is_not():
    """A floor receiver 1 mm in front of a wall disk (radius 25 mm) that reaches below the
    floor, as where a box stands on a floor: half the disk is a peak 1 mm wide that 256
    sub-area points resolve badly. The exact polygon integral matches brute force over
    the disk within 1 % (a 16-gon is not a disk; measured 5e-6 here), the mean over the
    sub-area points errs by more than 10 % (measured: +71 %, a bright speck)."""
    receivers = _receivers([[0.0, 0.0, 0.999]], [[0, 1, 0]], eye=[0, 1, -3])
    disks = _disks([[0.003, 0.01, 1.0]], [[0, 0, -1]], [np.pi * 0.025 ** 2])
    d, _ = transfer(receivers, disks, np.ones((1, 1)), None, solid_angle=0.01,
                    tolerance=0.0)
    exact = _brute_force(receivers, disks, lambda w: np.ones(w.shape[:-1] + (1,)),
                         rings=2000, sectors=2000)[0, 0, 0] / np.pi
    assert d[0, 0] == pytest.approx(exact, rel=0.01)
    sampled = _sample_mean_geometry(receivers, disks) / np.pi
    assert abs(sampled / exact - 1) > 0.1


def _sample_mean_geometry(receivers, disks):
    """|A| mean G over all of the disk's sub-area points (the estimator before exact
    integration)."""
    d = disks.points[0] - receivers.position[0]
    r2 = np.sum(d * d, -1)
    w = d / np.sqrt(r2)[:, None]
    g = np.maximum(w @ receivers.normal[0], 0) * np.maximum(-(w @ disks.normal[0]), 0) / r2
    return disks.area[0] * g.mean()


def test_near_entries_are_split_off_exactly_and_the_far_part_stays_smooth():
    """A smooth row with a spike (one entry carrying half the product, as beside a
    contact): far + near = row; the spike alone is near, replaced in the far part by its
    neighbours' mean; a row without a dominant entry has no near entries."""
    area = np.full(1000, 2.0)  # 1000 entries: each of a smooth row carries ≈ 0.1 %
    row = 1.0 + 0.001 * np.arange(1000)
    spiky = row.copy()
    spiky[20] = 1000.0
    far, (near_row, near_column, near_value) = split_near(np.stack([row, spiky]), area)
    near = np.zeros_like(far)
    near[near_row, near_column] = near_value
    np.testing.assert_allclose(far + near, np.stack([row, spiky]))
    assert near_row.tolist() == [1] and near_column.tolist() == [20]
    assert far[1, 20] == pytest.approx(0.5 * (row[19] + row[21]))


def test_runs_of_near_entries_take_the_far_neighbours_beside_the_run():
    """Adjacent near entries form a run, filled with the mean of the far entries on
    either side of it; at a row's ends only the one side that exists counts."""
    area = np.full(1000, 2.0)
    row = 1.0 + 0.001 * np.arange(1000)
    spikes = row.copy()
    runs = [[0, 1], [500, 501, 502], [999]]
    for run in runs:
        spikes[run] = 1000.0
    far, (near_row, near_column, near_value) = split_near(np.stack([row, spikes]), area)
    assert near_row.tolist() == [1] * 6 and near_column.tolist() == sum(runs, [])
    np.testing.assert_allclose(far[1, [0, 1]], row[2])
    np.testing.assert_allclose(far[1, 500:503], 0.5 * (row[499] + row[503]))
    np.testing.assert_allclose(far[1, 999], row[998])
    np.testing.assert_allclose(far[1, near_column] + near_value, spikes[near_column])
    np.testing.assert_array_equal(far[0], row)


def test_columns_without_source_area_are_interpolated_and_do_not_bias_truncated_products():
    """Columns of gathers without area and the padding take the linear interpolation of
    their sourced neighbours (the last sourced value beyond it); sourced columns are
    unchanged. With 6 % of scattered holes in a smooth row, the product with a radiance
    vector (zero at the holes, as |A| L is) after truncation to 64 of 2048 Haar
    coefficients loses ≈ the hole share when the holes stay zeros (the truncation keeps
    their coarse share), and keeps the product to 0.1 % once filled (measured: 1e-5):
    the filled row is smooth, so its 64 largest coefficients hold it."""
    from pipeline.math import haar
    from pipeline.methods.d2i.transfer import fill_sourceless

    rng = np.random.default_rng(3)
    count = 2000
    area = rng.uniform(0.5, 1.5, count)
    area[rng.random(count) < 0.06] = 0.0
    area[[0, count - 1]] = [0.0, 1.0]
    x = np.linspace(0.0, 1.0, count)
    smooth = 1.0 + 0.5 * np.sin(3.0 * x)
    rows = np.stack([smooth * (area > 0)])  # per unit area: 0 where there is no source
    length = haar.padded_length(count)
    filled = fill_sourceless(rows, area, length)
    sourced = np.flatnonzero(area > 0)
    np.testing.assert_array_equal(filled[0, sourced], rows[0, sourced])
    hole = np.flatnonzero(area == 0)[1]  # an interior hole: between its sourced neighbours
    left, right = sourced[sourced < hole][-1], sourced[sourced > hole][0]
    expect = np.interp(hole, [left, right], [smooth[left], smooth[right]])
    assert filled[0, hole] == pytest.approx(expect)
    assert filled[0, 0] == smooth[sourced[0]]                       # before the first
    np.testing.assert_array_equal(filled[0, count:], smooth[count - 1])  # the padding

    radiance = np.zeros(length)
    radiance[:count] = area * rng.uniform(0.8, 1.2, count)
    exact = float(rows[0] @ radiance[:count])

    def truncated_product(row: np.ndarray) -> float:
        kept = haar.truncate(haar.forward(row[None]), 0.0, 64)
        dense = np.zeros(length)
        dense[kept["index"]] = kept["value"]
        return float(dense @ haar.forward(radiance[None])[0])

    hole_share = 1.0 - (area > 0).mean()
    assert 1.0 - truncated_product(rows[0]) / exact > 0.5 * hole_share
    assert truncated_product(filled[0]) == pytest.approx(exact, rel=1e-3)


def test_compressed_rows_keep_products_where_a_near_spike_borders_a_sourceless_column():
    """compress_rows on a smooth row with 6 % of scattered columns without area and a
    near spike (half the product, as beside a contact) right beside one of them: the
    stored row's product with a radiance vector (zero where there is no area) keeps the
    exact one to 0.1 % at a 64-coefficient cap (with the holes left as zeros: −2 %)."""
    from pipeline.math import haar
    from pipeline.methods.d2i.stages.transfer import compress_rows

    rng = np.random.default_rng(5)
    count = 2000
    area = rng.uniform(0.5, 1.5, count)
    area[rng.random(count) < 0.06] = 0.0
    area[[700, 702]] = 0.0
    row = (1.0 + 0.5 * np.sin(3.0 * np.linspace(0.0, 1.0, count))) * (area > 0)
    row[701] = row.sum() * np.mean(area[area > 0]) / area[701]  # half the product
    radiance = area * rng.uniform(0.8, 1.2, count)
    stored = compress_rows(row[None], area, 0.0, 64)
    length = haar.padded_length(count)
    haar_part = stored["index"] < length
    dense = np.zeros(length)
    dense[stored["index"][haar_part]] = stored["value"][haar_part]
    padded = np.zeros(length)
    padded[:count] = radiance
    product = dense @ haar.forward(padded[None])[0] + \
        stored["value"][~haar_part] @ radiance[stored["index"][~haar_part] - length]
    assert stored["index"][~haar_part].tolist() == [length + 701]
    assert product == pytest.approx(row @ radiance, rel=1e-3)
