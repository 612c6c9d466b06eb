/* Method triple: a pixel's rows and weights from its G-buffer entry, on the device.
 * The OpenCL twin of pipeline/methods/triple/frame_grids.py (FrameGrid.weights, ViewGrid.weights)
 * and pipeline/methods/triple/render.py (texel_lookups, brdf_lookups); read their docstrings
 * for the conventions. Per shaded pixel the G-buffer holds (pipeline/render/
 * triple_gbuffer.py): the unit shading normal n and tangent t ⊥ n (world), the unit
 * direction toward the camera, the continuous texel coordinates and object of the
 * visibility texture, materials a and b and the blend t_b (weight of b).
 *
 *   lighting    8 frames of the rotation grid around the shading frame (t, n × t, n),
 *               ZYZ Euler angles about the +y pole, φ shifted by −turn (the map's
 *               rotation about +y at run time), trilinear weights;
 *   visibility  4 texels around the texel coordinates, bilinear, texels that hold no
 *               row (row −1) left out and the others renormalised;
 *   BRDF        9 rows: a's diffuse row × ((1 − t_b) kd_a + t_b kd_b), a's 4 glossy rows
 *               at the nearest local views × (1 − t_b) ρs_a × bilinear, b's × t_b ρs_b
 *               (glossy_base −1: a Lambertian material, weight 0).
 *
 * The trigonometry (the frame's Euler angles, the local view's angles) depends on the
 * camera only: triple_angles_of runs once per camera and stores grid coordinates; the
 * per-frame part (triple_lookups_of) applies the map's turn and the materials. */
#ifndef PRT_TRIPLE_LOOKUP_H
#define PRT_TRIPLE_LOOKUP_H

#include "inline.h"

#include "fastmath.h"

#define TRIPLE_LIGHT_ROWS 8
#define TRIPLE_VIS_ROWS 4
#define TRIPLE_BRDF_ROWS 9
#define TRIPLE_PI 3.14159265358979f
#define TRIPLE_TWO_PI 6.28318530717959f

/* Grid and table descriptions the lookups need. */
typedef struct {
    int n_phi, n_theta, n_psi;  /* the rotation grid (FrameGrid) */
    int view_phi, view_theta;   /* the view grid (ViewGrid) */
    float turn;                 /* the map's rotation about +y, radians */
} triple_grids;

/* One pixel's rows and weights (weights 0 where a row is absent). */
typedef struct {
    uint light_rows[TRIPLE_LIGHT_ROWS];
    float light_weight[TRIPLE_LIGHT_ROWS];
    uint vis_rows[TRIPLE_VIS_ROWS];
    float vis_weight[TRIPLE_VIS_ROWS];
    uint brdf_rows[TRIPLE_BRDF_ROWS];
    float3 brdf_weight[TRIPLE_BRDF_ROWS];
} triple_lookup;

/* frame_grids._linear: lower, upper index and upper weight of grid coordinate x. */
inline void triple_linear(float x, int count, int wrap, int* lo, int* hi, float* frac) {
    if (wrap) {
        float f = floor(x);
        *frac = x - f;
        int l = (int)f % count;
        if (l < 0) l += count;
        *lo = l;
        *hi = l + 1 == count ? 0 : l + 1;
    } else {
        x = clamp(x, 0.0f, (float)(count - 1));
        int l = min((int)floor(x), count - 2);
        *lo = l;
        *hi = l + 1;
        *frac = x - (float)l;
    }
}

/* φ mod 2π in [0, 2π). */
inline float triple_wrap_angle(float a) {
    a -= TRIPLE_TWO_PI * floor(a / TRIPLE_TWO_PI);
    return a >= TRIPLE_TWO_PI ? 0.0f : a;
}

/* The frame's grid coordinates (φ, θ, ψ in units of the grid steps; φ before the map's
 * turn) of the frame (t, n × t, n): euler_angles in the pole basis [A | B | P] =
 * [+z | +x | +y], i.e. n' = (n.z, n.x, n.y). Per camera (kernel triple_angles). */
PRT_INLINE float3 triple_frame_coords(float3 n, float3 t, const triple_grids* g) {
    float3 np = (float3)(n.z, n.x, n.y), tp = (float3)(t.z, t.x, t.y);
    float cos_theta = clamp(np.z, -1.0f, 1.0f), sin_theta = sqrt(np.x * np.x + np.y * np.y);
    float theta = fast_atan2(sin_theta, cos_theta);  /* arccos(n'_z), sharper at poles */
    int at_pole = sin_theta < 1e-9f;
    float phi = at_pole ? 0.0f : triple_wrap_angle(fast_atan2(np.y, np.x));
    /* the reference frame Rz(φ) Ry(θ): cos, sin of φ and θ from n' itself (no trig) */
    float cp = at_pole ? 1.0f : np.x / sin_theta, sp = at_pole ? 0.0f : np.y / sin_theta;
    float3 ref_t = (float3)(cp * cos_theta, sp * cos_theta, -sin_theta);
    float3 ref_b = (float3)(-sp, cp, 0.0f);
    float psi = triple_wrap_angle(fast_atan2(dot(tp, ref_b), dot(tp, ref_t)));
    return (float3)(phi * g->n_phi / TRIPLE_TWO_PI, theta * (g->n_theta - 1) / TRIPLE_PI,
                    psi * g->n_psi / TRIPLE_TWO_PI);
}

/* FrameGrid.weights from the grid coordinates x, the map turned by g->turn (φ − turn):
 * the 8 entries (j·n_θ + i)·n_ψ + k around it and their trilinear weights. Per frame. */
PRT_INLINE void triple_frame_rows(float3 x, const triple_grids* g, uint* rows, float* weight) {
    int j[2], i[2], k[2];
    float wj, wi, wk;
    triple_linear(x.x - g->turn * g->n_phi / TRIPLE_TWO_PI, g->n_phi, 1, &j[0], &j[1], &wj);
    triple_linear(x.y, g->n_theta, 0, &i[0], &i[1], &wi);
    triple_linear(x.z, g->n_psi, 1, &k[0], &k[1], &wk);
    float a[2] = {1.0f - wj, wj}, b[2] = {1.0f - wi, wi}, c[2] = {1.0f - wk, wk};
    int e = 0;
    for (int p = 0; p < 2; ++p)
        for (int q = 0; q < 2; ++q)
            for (int r = 0; r < 2; ++r, ++e) {
                rows[e] = (uint)((j[p] * g->n_theta + i[q]) * g->n_psi + k[r]);
                weight[e] = a[p] * b[q] * c[r];
            }
}

/* The view grid coordinates (φ_o, θ_o in grid steps) of the local view wo; a view at or
 * below the shading frame's horizon gets θ_o = TRIPLE_BELOW (every BRDF is zero there,
 * pipeline/math/brdf.py, so the pixel's BRDF weights are). Per camera. */
#define TRIPLE_BELOW (-1.0f)
PRT_INLINE float2 triple_view_coords(float3 wo, const triple_grids* g) {
    float phi = triple_wrap_angle(fast_atan2(wo.y, wo.x));
    if (!(wo.z > 0.0f)) return (float2)(phi * g->view_phi / TRIPLE_TWO_PI, TRIPLE_BELOW);
    float theta = fast_atan2(sqrt(wo.x * wo.x + wo.y * wo.y), wo.z);
    return (float2)(phi * g->view_phi / TRIPLE_TWO_PI,
                    theta * (g->view_theta - 1) / (0.5f * TRIPLE_PI));
}

/* ViewGrid.weights from the view grid coordinates: entries j·n_θ + i and bilinear
 * weights. */
inline void triple_view_rows(float2 x, const triple_grids* g, int* entries, float* weight) {
    int j[2], i[2];
    float wj, wi;
    triple_linear(x.x, g->view_phi, 1, &j[0], &j[1], &wj);
    triple_linear(x.y, g->view_theta, 0, &i[0], &i[1], &wi);
    float a[2] = {1.0f - wj, wj}, b[2] = {1.0f - wi, wi};
    for (int p = 0; p < 2; ++p)
        for (int q = 0; q < 2; ++q) {
            entries[2 * p + q] = j[p] * g->view_theta + i[q];
            weight[2 * p + q] = a[p] * b[q];
        }
}

/* texel_lookups at continuous texel coordinates xy of a texture (height, width) whose
 * texel (i, j) is flat texel offset + i·width + j; texel_row[flat] its visibility row
 * (−1: empty). */
inline void triple_texel_weights(float2 xy, int height, int width, int offset,
                                 __global const int* texel_row, uint* rows, float* weight) {
    float x = clamp(xy.x - 0.5f, 0.0f, (float)(width - 1));
    float y = clamp(xy.y - 0.5f, 0.0f, (float)(height - 1));
    int x0 = min((int)floor(x), max(width - 2, 0)), y0 = min((int)floor(y), max(height - 2, 0));
    float fx = x - (float)x0, fy = y - (float)y0;
    int x1 = min(x0 + 1, width - 1), y1 = min(y0 + 1, height - 1);
    int flat[4] = {offset + y0 * width + x0, offset + y0 * width + x1,
                   offset + y1 * width + x0, offset + y1 * width + x1};
    float w[4] = {(1.0f - fy) * (1.0f - fx), (1.0f - fy) * fx, fy * (1.0f - fx), fy * fx};
    float total = 0.0f;
    for (int r = 0; r < 4; ++r) {
        int row = texel_row[flat[r]];
        if (row < 0) w[r] = 0.0f;
        rows[r] = row < 0 ? 0u : (uint)row;
        total += w[r];
    }
    for (int r = 0; r < 4; ++r) weight[r] = total > 0.0f ? w[r] / total : 0.0f;
}

/* The camera's part of pixel i's lookups (kernel triple_angles, once per camera): the
 * grid coordinates of its shading frame and of its local view ω_o in (t, n × t, n), as
 * brdf.to_local. G-buffer arrays as triple_gbuffer.py's GBuffer. */
inline void triple_angles_of(int i, __global const float* normal,
                             __global const float* tangent, __global const float* view,
                             const triple_grids* g, float3* frame, float2* view_coords) {
    float3 n = vload3(i, normal), t = vload3(i, tangent), v = vload3(i, view);
    *frame = triple_frame_coords(n, t, g);
    *view_coords = triple_view_coords((float3)(dot(v, t), dot(v, cross(n, t)), dot(v, n)), g);
}

/* All of pixel i's rows and weights, per frame: from the camera's grid coordinates
 * (frame_coords P·3, view_coords P·2) and the G-buffer's texel_xy (P·2), object,
 * material_a, material_b (P), blend (P); per object its texture (height, width, offset)
 * in object_texture (objects·3); per material glossy_base, diffuse_row (int) and kd,
 * rho_s (materials·3). */
inline void triple_lookups_of(int i, __global const float* frame_coords,
                              __global const float* view_coords,
                              __global const float* texel_xy, __global const int* object,
                              __global const int* material_a, __global const int* material_b,
                              __global const float* blend,
                              __global const int* object_texture,
                              __global const int* texel_row,
                              __global const int* glossy_base,
                              __global const int* diffuse_row,
                              __global const float* kd, __global const float* rho_s,
                              const triple_grids* g, triple_lookup* out) {
    triple_frame_rows(vload3(i, frame_coords), g, out->light_rows, out->light_weight);
    int o = object[i];
    triple_texel_weights(vload2(i, texel_xy), object_texture[3 * o], object_texture[3 * o + 1],
                         object_texture[3 * o + 2], texel_row, out->vis_rows,
                         out->vis_weight);
    int entries[4];
    float w[4];
    float2 view = vload2(i, view_coords);
    float above = view.y == TRIPLE_BELOW ? 0.0f : 1.0f;
    triple_view_rows(view, g, entries, w);
    int ma = material_a[i], mb = material_b[i];
    float tb = blend[i];
    out->brdf_rows[0] = (uint)diffuse_row[ma];
    out->brdf_weight[0] = above * ((1.0f - tb) * vload3(ma, kd) + tb * vload3(mb, kd));
    int m[2] = {ma, mb};
    float share[2] = {1.0f - tb, tb};
    for (int s = 0; s < 2; ++s) {
        int base = glossy_base[m[s]];
        float3 rs = vload3(m[s], rho_s) * (share[s] * above);
        for (int e = 0; e < 4; ++e) {
            out->brdf_rows[1 + 4 * s + e] = base >= 0 ? (uint)(base + entries[e]) : 0u;
            out->brdf_weight[1 + 4 * s + e] = base >= 0 ? w[e] * rs : (float3)(0.0f);
        }
    }
}

#endif
