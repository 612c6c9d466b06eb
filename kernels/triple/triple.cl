/* Method triple (paper 004): per pixel, the triple product ∫ L V ρ̃ dω_i in the pixel's
 * local frame, from interpolated wavelet rows (sphwavelet.h):
 *   L  the environment map resampled in the nearest frames of the rotation grid
 *      (TRIPLE_LIGHT_ROWS rows, RGB values, trilinear weights),
 *   V  the visibility of the nearest texels of the object's visibility texture
 *      (TRIPLE_VIS_ROWS rows, grey values, bilinear weights),
 *   ρ̃  kd · (cos θ_i / π) + ρs · f_g(ω_i, ω_o) cos θ_i: the diffuse row weighted by kd
 *      and the glossy rows at the nearest local views weighted by ρs × the bilinear
 *      weights, for a blend of two materials (TRIPLE_BRDF_ROWS rows, grey values, RGB
 *      weights).
 * Rows and weights come from the G-buffer (triple_lookup.h; `triple_lookups` writes
 * them out for the sparse path and the tests); pipeline/methods/triple/render.py and
 * triple_dense.py hold the NumPy twins. */
#define SW_ROWS 9
#ifndef TRIPLE_T  /* triangles and vector width of the dense path; defaults when unused */
#define TRIPLE_T 20
#endif
#ifndef TRIPLE_W
#define TRIPLE_W 4
#endif
#include "vectorize.h"
#include "sphwavelet.h"
#include "triple_lookup.h"
#include "envmap.h"

#define TRIPLE_GBUFFER_ARGS                                                              \
    __global const float *frame_coords, __global const float *view_coords,               \
    __global const float *texel_xy,                                                      \
    __global const int *object, __global const int *material_a,                          \
    __global const int *material_b, __global const float *blend,                         \
    __global const int *object_texture, __global const int *texel_row,                   \
    __global const int *glossy_base, __global const int *diffuse_row,                    \
    __global const float *kd, __global const float *rho_s, const int n_phi,              \
    const int n_theta, const int n_psi, const int view_phi, const int view_theta,        \
    const float turn
#define TRIPLE_LOOKUP(i, g, look)                                                        \
    triple_grids g = {n_phi, n_theta, n_psi, view_phi, view_theta, turn};                \
    triple_lookup look;                                                                  \
    triple_lookups_of(i, frame_coords, view_coords, texel_xy, object, material_a, material_b, \
                      blend, object_texture, texel_row, glossy_base, diffuse_row, kd,    \
                      rho_s, &g, &look)

/* Per camera: the grid coordinates of every G-buffer pixel's shading frame (P·3) and
 * local view (P·2): the lookups' trigonometry, done once while the camera stays. */
__kernel void triple_angles(__global const float* normal, __global const float* tangent,
                            __global const float* view, const int n_phi, const int n_theta,
                            const int n_psi, const int view_phi, const int view_theta,
                            const int n, __global float* frame_coords,
                            __global float* view_coords)
{
    int i = get_global_id(0);
    if (i >= n) return;
    triple_grids g = {n_phi, n_theta, n_psi, view_phi, view_theta, 0.0f};
    float3 frame;
    float2 v;
    triple_angles_of(i, normal, tangent, view, &g, &frame, &v);
    vstore3(frame, i, frame_coords);
    vstore2(v, i, view_coords);
}

/* The rows and weights of every G-buffer pixel (for the sparse path and the tests). */
__kernel void triple_lookups(TRIPLE_GBUFFER_ARGS, const int n,
                             __global uint* light_rows, __global float* light_weight,
                             __global uint* vis_rows, __global float* vis_weight,
                             __global uint* brdf_rows, __global float* brdf_weight)
{
    int i = get_global_id(0);
    if (i >= n) return;
    TRIPLE_LOOKUP(i, g, look);
    for (int r = 0; r < TRIPLE_LIGHT_ROWS; ++r) {
        light_rows[TRIPLE_LIGHT_ROWS * i + r] = look.light_rows[r];
        light_weight[TRIPLE_LIGHT_ROWS * i + r] = look.light_weight[r];
    }
    for (int r = 0; r < TRIPLE_VIS_ROWS; ++r) {
        vis_rows[TRIPLE_VIS_ROWS * i + r] = look.vis_rows[r];
        vis_weight[TRIPLE_VIS_ROWS * i + r] = look.vis_weight[r];
    }
    for (int r = 0; r < TRIPLE_BRDF_ROWS; ++r) {
        brdf_rows[TRIPLE_BRDF_ROWS * i + r] = look.brdf_rows[r];
        vstore3(look.brdf_weight[r], TRIPLE_BRDF_ROWS * i + r, brdf_weight);
    }
}

/* General path: sparse rows of any selection and budget, merged on the fly. */
PRT_SCALAR_ITEMS
__kernel void triple_shade(__global const uint* light_start, __global const ushort* light_index,
                           __global const float* light_value,
                           __global const uint* vis_start, __global const ushort* vis_index,
                           __global const float* vis_value,
                           __global const uint* brdf_start, __global const ushort* brdf_index,
                           __global const float* brdf_value,
                           __global const uint* light_rows,    /* n * 8 */
                           __global const float* light_weight, /* n * 8 */
                           __global const uint* vis_rows,      /* n * 4 */
                           __global const float* vis_weight,   /* n * 4 */
                           __global const uint* brdf_rows,     /* n * 9 */
                           __global const float* brdf_weight,  /* n * 9 * 3 */
                           __global const float* root_area,
                           __global const float* wavelet,
                           __global const float* tensor,
                           const int n,
                           __global float* out)                /* n * 3 */
{
    int i = get_global_id(0);
    if (i >= n) return;
    uint rows[SW_ROWS];
    float3 w[SW_ROWS];
    sw_source src[3];
    int k = 0;
    for (int r = 0; r < TRIPLE_LIGHT_ROWS; ++r) {
        float x = light_weight[TRIPLE_LIGHT_ROWS * i + r];
        if (x == 0.0f) continue;
        rows[k] = light_rows[TRIPLE_LIGHT_ROWS * i + r];
        w[k++] = (float3)(x);
    }
    sw_open(&src[0], light_start, light_index, light_value, 3, rows, w, k);
    k = 0;
    for (int r = 0; r < TRIPLE_VIS_ROWS; ++r) {
        float x = vis_weight[TRIPLE_VIS_ROWS * i + r];
        if (x == 0.0f) continue;
        rows[k] = vis_rows[TRIPLE_VIS_ROWS * i + r];
        w[k++] = (float3)(x);
    }
    sw_open(&src[1], vis_start, vis_index, vis_value, 1, rows, w, k);
    k = 0;
    for (int r = 0; r < TRIPLE_BRDF_ROWS; ++r) {
        float3 x = vload3(TRIPLE_BRDF_ROWS * i + r, brdf_weight);
        if (x.x == 0.0f && x.y == 0.0f && x.z == 0.0f) continue;
        rows[k] = brdf_rows[TRIPLE_BRDF_ROWS * i + r];
        w[k++] = x;
    }
    sw_open(&src[2], brdf_start, brdf_index, brdf_value, 1, rows, w, k);
    vstore3(sw_triple(src, root_area, wavelet, tensor), i, out);
}

/* Dense top-only path (build with -D TRIPLE_T=20·4^k, -D TRIPLE_W=4 or 8 dividing it): a
 * top-only budget ≤ 20·4^k is a function constant on the T level-k triangles, so the
 * triple product is
 *     Σ_t A_t L_t V_t ρ̃_t
 * with per-triangle values (dense.py): light (rows · 3 · T, planar R, G, B rows, × A_t)
 * over light_scale (rows), visibility (rows · T) and BRDF (rows · T) over brdf_scale,
 * stored as half (converted as loaded; a row's scale goes into its weight). The
 * interpolation weights sum the rows W triangles at a time (vector loads, no gathers);
 * a block where V is 0 reads no light or BRDF. */
#if TRIPLE_W == 8
typedef float8 triple_vec;
#define TRIPLE_VLOAD vload_half8
inline float triple_hsum(float8 x) {
    float4 a = x.lo + x.hi;
    return a.x + a.y + a.z + a.w;
}
#else
typedef float4 triple_vec;
#define TRIPLE_VLOAD vload_half4
inline float triple_hsum(float4 x) { return x.x + x.y + x.z + x.w; }
#endif

__kernel void triple_shade_dense(__global const half* light,
                                 __global const float* light_scale,
                                 __global const half* vis, __global const half* brdf,
                                 __global const float* brdf_scale, TRIPLE_GBUFFER_ARGS,
                                 const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    TRIPLE_LOOKUP(i, g, look);
    __global const half* lrow[TRIPLE_LIGHT_ROWS];
    __global const half* vrow[TRIPLE_VIS_ROWS];
    __global const half* brow[TRIPLE_BRDF_ROWS];
    float lw[TRIPLE_LIGHT_ROWS], vw[TRIPLE_VIS_ROWS];
    float3 bw[TRIPLE_BRDF_ROWS];
    int nl = 0, nv = 0, nb = 0;  /* rows of non-zero weight */
    for (int r = 0; r < TRIPLE_LIGHT_ROWS; ++r)
        if (look.light_weight[r] != 0.0f) {
            lrow[nl] = light + (size_t)look.light_rows[r] * (3 * TRIPLE_T);
            lw[nl++] = look.light_weight[r] * light_scale[look.light_rows[r]];
        }
    for (int r = 0; r < TRIPLE_VIS_ROWS; ++r)
        if (look.vis_weight[r] != 0.0f) {
            vrow[nv] = vis + (size_t)look.vis_rows[r] * TRIPLE_T;
            vw[nv++] = look.vis_weight[r];
        }
    for (int r = 0; r < TRIPLE_BRDF_ROWS; ++r) {
        float3 x = look.brdf_weight[r];
        if (x.x != 0.0f || x.y != 0.0f || x.z != 0.0f) {
            brow[nb] = brdf + (size_t)look.brdf_rows[r] * TRIPLE_T;
            bw[nb++] = x * brdf_scale[look.brdf_rows[r]];
        }
    }
    triple_vec sr = (triple_vec)(0.0f), sg = (triple_vec)(0.0f), sb = (triple_vec)(0.0f);
    for (int q = 0; q < TRIPLE_T / TRIPLE_W; ++q) {
        triple_vec v = (triple_vec)(0.0f);
        for (int r = 0; r < nv; ++r) v += vw[r] * TRIPLE_VLOAD(q, vrow[r]);
        if (!any(v != (triple_vec)(0.0f))) continue;  /* occluded: nothing to read */
        triple_vec lr = (triple_vec)(0.0f), lg = (triple_vec)(0.0f), lb = (triple_vec)(0.0f);
        for (int r = 0; r < nl; ++r) {
            lr += lw[r] * TRIPLE_VLOAD(q, lrow[r]);
            lg += lw[r] * TRIPLE_VLOAD(q, lrow[r] + TRIPLE_T);
            lb += lw[r] * TRIPLE_VLOAD(q, lrow[r] + 2 * TRIPLE_T);
        }
        triple_vec br = (triple_vec)(0.0f), bg = (triple_vec)(0.0f), bb = (triple_vec)(0.0f);
        for (int r = 0; r < nb; ++r) {
            triple_vec x = TRIPLE_VLOAD(q, brow[r]);
            br += bw[r].x * x;
            bg += bw[r].y * x;
            bb += bw[r].z * x;
        }
        sr += v * lr * br;
        sg += v * lg * bg;
        sb += v * lb * bb;
    }
    vstore3((float3)(triple_hsum(sr), triple_hsum(sg), triple_hsum(sb)), i, out);
}

/* Background of the pixels that miss: the environment map (rotated by turn about +y,
 * × scale) at their map coordinates in the unrotated map (n · 2, (u, v) as envmap.py's
 * direction_to_uv, per camera): the turn only shifts u by turn/2π (the map-space
 * direction is R_y(−turn) d, whose atan2(x, −z) is d's plus turn), so no trigonometry
 * per frame; envmap.h's bilinear lookup. */
__kernel void triple_background(__global const float* rgb, const int width, const int height,
                                __global const float* uv, const float turn,
                                const float scale, const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float2 c = vload2(i, uv);
    float u = c.x + turn * (0.5f / TRIPLE_PI);
    u -= floor(u);
    float x = u * width - 0.5f, y = c.y * (height - 1);
    float x0 = floor(x), y0 = floor(y);
    vstore3(scale * envmap_bilinear(rgb, width, height, (int)x0, (int)y0, x - x0, y - y0),
            i, out);
}

/* The map coordinates (u, v) of the missing rays' unit directions (n · 3) in the
 * unrotated map, as triple_background reads them, run once per camera: envmap.h's
 * mapping (envmap_texel_coords before its texel scale; host twin envmap.py
 * direction_to_uv). */
__kernel void triple_miss_uv(__global const float* direction, const int n, __global float* uv)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 d = vload3(i, direction);
    float u = atan2(d.x, -d.z) * (0.5f / ENVMAP_PI);
    vstore2((float2)(u - floor(u), acos(clamp(d.y, -1.0f, 1.0f)) * (1.0f / ENVMAP_PI)), i, uv);
}
