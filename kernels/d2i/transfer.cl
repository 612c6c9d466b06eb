/* Transfer entries of method d2i with sub-area sampling: the OpenCL twin of
 * pipeline/methods/d2i/transfer.py (see its docstring for the estimators, the sample counts and
 * the convergence rule). Only visible pairs are launched: the host lists them as
 * pair = p * disk_count + g (receiver p, gather disk g) and zero-fills the outputs.
 * transfer_points takes every listed pair whose disk spans at most solid_angle (one
 * sample at its centre: 99 % of the pairs on the Cornell box's small box) and flags
 * the others in deferred[k]; transfer_pairs takes those (sub-area samples, the exact
 * polygon integral). Measured on 128 of the box's pixels at 16k gathers (PoCL, one
 * core): 89-144 ms per launch with one work-item per pair, the invisible ones
 * included, against 28-55 ms so (decision 0016). transfer_points is
 * written for PoCL's vectoriser (scalar arithmetic, padded pairs, only the stores
 * guarded, no libm call: kernels/triple/brdf_tables.cl; that it is vectorised is not
 * confirmed; the rewrite measured 14-20 % faster); its values match the general path's
 * to float rounding.
 *
 * Defines: ROWS = rows of T (k + 1; 0 for receivers that only need D or Ms),
 *          SUBAREA = points per disk pattern (a power of two), FIRST_CHECK = 4,
 *          POLYGON_SIDES = vertices of the polygon that stands for a disk,
 *          PLANE_MARGIN = receivers nearer a disk's plane (x its radius) get nothing.
 *
 * Receivers: 12 floats each: position, normal, tangent, wo (world, unit normal/tangent/wo).
 * Disks:      8 floats each: centre, normal, area, unused.
 * Points:     SUBAREA * 3 floats per disk: its sub-area sample points (world); a pair
 *             with one sample uses the disk's centre instead (a point gather sample).
 * Polygons:   POLYGON_SIDES * 3 floats per disk: the equal-area polygon's vertices; a
 *             pair with more than one sample integrates G exactly over it.
 * Table:      ROWS * h floats: b0, b1..bk tabulated on the ascending coordinate grid
 *             grid[h] (delta in radians, or Lafortune's lobe base x); the cell of a value
 *             is found from its angle a (delta, or arccos x): f = (a - angle_lo) *
 *             angle_scale, reversed when REVERSED_GRID (Lafortune), and the weight
 *             linearly in the coordinate, as numpy.interp does.
 */
#include "inline.h"
#include "brdf.h"

#define FORM_FACTOR_CAP 3.14159265358979f

/* The cell i and weight w of a coordinate on the grid: the value of a row there is
 * row[i] + w (row[i + 1] - row[i]). */
PRT_INLINE int table_cell(__global const float* grid, int h, float coord, float angle, float angle_lo,
               float angle_scale, float* w) {
    float f = (angle - angle_lo) * angle_scale;
#ifdef REVERSED_GRID
    f = (float)(h - 1) - f;
#endif
    int i = (int)f;
    i -= f < (float)i ? 1 : 0;                  /* floor, no libm call */
    i = clamp(i, 0, h - 2);
    if (coord < grid[i] && i > 0) i -= 1;
    if (coord > grid[i + 1] && i < h - 2) i += 1;
    *w = clamp((coord - grid[i]) / (grid[i + 1] - grid[i]), 0.0f, 1.0f);
    return i;
}

#if ROWS > 0
/* rows[j] += geo * f_F(wi, wo) b_j(coordinate(wi, wo)) for every row j. */
PRT_INLINE void accumulate_rows(float* rows, __global const float* material,
                     __global const float* grid, __global const float* table, const int h,
                     const float angle_lo, const float angle_scale, float3 wi, float3 wo,
                     float geo) {
    float fixed = geo * brdf_fixed(material, wi, wo);
    float angle = brdf_coordinate_angle(material, wi, wo);
#ifdef REVERSED_GRID
    float coord = cos(angle);
#else
    float coord = angle;
#endif
    float w;
    int i = table_cell(grid, h, coord, angle, angle_lo, angle_scale, &w);
    __global const float* cell = table + i;
#pragma unroll
    for (int j = 0; j < ROWS; ++j, cell += h)
        rows[j] += fixed * (cell[0] + w * (cell[1] - cell[0]));
}
#endif

/* Lambert's formula term of the edge a -> b (relative to the receiver). */
PRT_INLINE float edge_term(float3 a, float3 b, float3 n) {
    float3 ua = normalize(a), ub = normalize(b);
    float3 c = cross(ua, ub);
    float s = length(c);
    return s > 0.0f ? fast_atan2(s, dot(ua, ub)) * dot(c, n) / s : 0.0f;
}

/* The integral of G over the polygon clipped to the receiver's upper half-space
 * (pipeline.methods.d2i.transfer.polygon_geometry), and the clipped polygon's vertex mean
 * (relative to x) in *centroid. */
PRT_INLINE float polygon_geometry(__global const float* poly, float3 x, float3 n,
                              float3* centroid) {
    float3 first = (float3)(0.0f), prev = (float3)(0.0f), sum = (float3)(0.0f);
    float total = 0.0f;
    int emitted = 0;
    float3 v = vload3(0, poly) - x;
    float h = dot(v, n);
    for (int i = 0; i < POLYGON_SIDES; ++i) {
        float3 v_next = vload3((i + 1) % POLYGON_SIDES, poly) - x;
        float h_next = dot(v_next, n);
        for (int part = 0; part < 2; ++part) {
            float3 point;
            if (part == 0) {
                if (h < 0.0f) continue;
                point = v;
            } else {
                if ((h >= 0.0f) == (h_next >= 0.0f)) continue;
                point = v + (h / (h - h_next)) * (v_next - v);
            }
            if (emitted == 0) first = point; else total += edge_term(prev, point, n);
            prev = point;
            sum += point;
            emitted += 1;
        }
        v = v_next;
        h = h_next;
    }
    if (emitted > 1) total += edge_term(prev, first, n);
    *centroid = emitted > 0 ? sum / (float)emitted : (float3)(0.0f);
    return 0.5f * fabs(total);
}

/* The pairs whose disk spans at most solid_angle (one sample, at its centre: nearly
 * all of them), in straight-line code; the others are flagged in deferred[k] for
 * transfer_pairs. pairs is padded to the global size (a multiple of the work-group
 * size) and only the stores are guarded, so that PoCL vectorises the work-item loop. */
__kernel void transfer_points(__global const float* receivers,
                              __global const float* disks, const int disk_count,
                              __global const uint* pairs, const int pair_count,
                              __global const float* material,
                              __global const float* grid, __global const float* table,
                              const int h, const float angle_lo, const float angle_scale,
                              const float solid_angle,
                              __global uchar* deferred,
                              __global float* d_out, __global float* t_out)
{
    int k = get_global_id(0);
    uint pair = pairs[k];
    int p = (int)(pair / (uint)disk_count), g = (int)(pair - (uint)p * (uint)disk_count);
    __global const float* disk = disks + 8 * g;
    __global const float* r = receivers + 12 * p;
    float area = disk[6];
    float dx = disk[0] - r[0], dy = disk[1] - r[1], dz = disk[2] - r[2];
    float nx = r[3], ny = r[4], nz = r[5], tx = r[6], ty = r[7], tz = r[8];
    float r2 = fmax(dx * dx + dy * dy + dz * dz, 1e-30f);
    float inv = 1.0f / sqrt(r2);
    float wx = dx * inv, wy = dy * inv, wz = dz * inv;
    float cos_x = fmax(wx * nx + wy * ny + wz * nz, 0.0f);
    float cos_g = fmax(-(wx * disk[3] + wy * disk[4] + wz * disk[5]), 0.0f);
    float geo = area * cos_x * cos_g / r2;
    bool near = SUBAREA > 1 && solid_angle < area / r2;
    bool store = k < pair_count && !near && area > 0.0f;
#if ROWS > 0
    /* the local frame (t, n x t, n) */
    float bx = ny * tz - nz * ty, by = nz * tx - nx * tz, bz = nx * ty - ny * tx;
    float3 wi = (float3)(wx * tx + wy * ty + wz * tz, wx * bx + wy * by + wz * bz,
                         wx * nx + wy * ny + wz * nz);
    float ox = r[9], oy = r[10], oz = r[11];
    float3 wo = (float3)(ox * tx + oy * ty + oz * tz, ox * bx + oy * by + oz * bz,
                         ox * nx + oy * ny + oz * nz);
    float sum[ROWS];
#pragma unroll
    for (int j = 0; j < ROWS; ++j) sum[j] = 0.0f;
    accumulate_rows(sum, material, grid, table, h, angle_lo, angle_scale, wi, wo, geo);
    if (store) {
#pragma unroll
        for (int j = 0; j < ROWS; ++j)
            t_out[((size_t)p * ROWS + j) * disk_count + g] = sum[j];
    }
#endif
    if (k < pair_count) deferred[k] = near;
    if (store) d_out[pair] = fmin(geo, FORM_FACTOR_CAP) * (1.0f / BRDF_PI);
}

__kernel void transfer_pairs(__global const float* receivers,
                             __global const float* disks, const int disk_count,
                             __global const float* points,
                             __global const float* polygons,
                             __global const uint* pairs,    /* visible p * disk_count + g */
                             const int pair_count,
                             __global const float* material,        /* MATERIAL_FLOATS */
                             __global const float* grid, __global const float* table,
                             const int h, const float angle_lo, const float angle_scale,
                             const float solid_angle, const float tolerance,
                             __global float* d_out,                 /* receiver x disk */
                             __global float* t_out)                 /* receiver x ROWS x disk */
{
    int k = get_global_id(0);
    if (k >= pair_count) return;
    uint pair = pairs[k];
    int p = (int)(pair / (uint)disk_count), g = (int)(pair - (uint)p * (uint)disk_count);
    __global const float* disk = disks + 8 * (size_t)g;
    float area = disk[6];
    if (area <= 0.0f) return;   /* its entries stay 0 */
    __global const float* r = receivers + 12 * (size_t)p;
    float3 x = vload3(0, r), nx = vload3(1, r), tx = vload3(2, r), wo_world = vload3(3, r);
    float3 centre = vload3(0, disk), ng = vload3(1, disk);
    float3 dc = centre - x;
    float omega = area / fmax(dot(dc, dc), 1e-30f);
    int count = 1;
    while (count < SUBAREA && (float)count * solid_angle < omega) count *= 2;
    float exact = 0.0f;
    float3 centroid = dc;
    /* a receiver in the disk's plane (to PLANE_MARGIN of its radius) sees it edge-on */
    if (count > 1 && dot(ng, -dc) > PLANE_MARGIN * sqrt(area / BRDF_PI))
        exact = polygon_geometry(polygons + (size_t)g * POLYGON_SIDES * 3, x, nx, &centroid);

#if ROWS > 0
    float3 wo = to_local(wo_world, nx, tx);
    float sum[ROWS], half_sum[ROWS];
    for (int j = 0; j < ROWS; ++j) { sum[j] = 0.0f; half_sum[j] = 0.0f; }
    float geo_sum = 0.0f;
    __global const float* q = points + (size_t)g * SUBAREA * 3;
    for (int i = 0; i < count; ++i) {
        float3 d = (count == 1 ? centre : vload3(i, q)) - x;
        float r2 = fmax(dot(d, d), 1e-30f);
        float3 w = d * rsqrt(r2);
        float geo = area * fmax(dot(w, nx), 0.0f) * fmax(-dot(w, ng), 0.0f) / r2;
        geo_sum += geo;
        accumulate_rows(sum, material, grid, table, h, angle_lo, angle_scale,
                        to_local(w, nx, tx), wo, geo);
        int n = i + 1;
        if (n >= FIRST_CHECK && (n & (n - 1)) == 0 && n < count) {
            if (n >= 2 * FIRST_CHECK) {
                float mean = sum[0] / n, first = half_sum[0] / (n / 2);
                if (fabs(2.0f * mean - 2.0f * first) <= tolerance * fabs(mean)) break;
            }
            for (int j = 0; j < ROWS; ++j) half_sum[j] = sum[j];
        }
    }
    if (count == 1) {
        for (int j = 0; j < ROWS; ++j)
            t_out[((size_t)p * ROWS + j) * disk_count + g] = sum[j];
    } else if (geo_sum > 0.0f) {
        /* the exact geometry integral times the samples' G-weighted BRDF mean */
        for (int j = 0; j < ROWS; ++j)
            t_out[((size_t)p * ROWS + j) * disk_count + g] = exact * sum[j] / geo_sum;
    } else {
        /* no sample sees the clipped polygon: the BRDF towards its centroid */
        float at_centroid[ROWS];
        for (int j = 0; j < ROWS; ++j) at_centroid[j] = 0.0f;
        accumulate_rows(at_centroid, material, grid, table, h, angle_lo, angle_scale,
                        to_local(normalize(centroid), nx, tx), wo, 1.0f);
        for (int j = 0; j < ROWS; ++j)
            t_out[((size_t)p * ROWS + j) * disk_count + g] = exact * at_centroid[j];
    }
    float point = geo_sum;
#else
    float point = 0.0f;
    if (count == 1) {
        float r2 = fmax(dot(dc, dc), 1e-30f);
        float3 w = dc * rsqrt(r2);
        point = area * fmax(dot(w, nx), 0.0f) * fmax(-dot(w, ng), 0.0f) / r2;
    }
#endif
    d_out[pair] = (count > 1 ? exact : fmin(point, FORM_FACTOR_CAP)) * (1.0f / BRDF_PI);
}
