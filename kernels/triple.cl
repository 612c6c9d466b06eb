/* Method triple (paper 004): per pixel, the triple product ∫ L V ρ̃ dω_i in the pixel's
 * local frame, from interpolated sparse wavelet rows (sphwavelet.h):
 *   L  the environment map resampled in the nearest frames of the rotation grid
 *      (TRIPLE_LIGHT_ROWS rows, RGB values, trilinear weights),
 *   V  the visibility of the nearest texels of the object's visibility texture
 *      (TRIPLE_VIS_ROWS rows, grey values, bilinear weights),
 *   ρ̃  kd · (cos θ_i / π) + ρs · f_g(ω_i, ω_o) cos θ_i: the material's diffuse row
 *      weighted by kd and its glossy rows at the nearest local views weighted by
 *      ρs × the bilinear weights, and for a blend (1 − t) a + t b the glossy rows of
 *      both materials (TRIPLE_BRDF_ROWS rows, grey values, RGB weights).
 * Rows and weights per pixel come from the host (pipeline/render/triple.py, whose NumPy
 * twin computes the same sums); a pixel with no rows (a miss) gets 0. */
#include "sphwavelet.h"

#define TRIPLE_LIGHT_ROWS 8
#define TRIPLE_VIS_ROWS 4
#define TRIPLE_BRDF_ROWS 9  /* diffuse + 4 glossy views of material a + 4 of b (blends);
                              built with SW_ROWS >= 9 */
#if SW_ROWS < TRIPLE_BRDF_ROWS
#error "kernels/triple.cl needs SW_ROWS >= TRIPLE_BRDF_ROWS"
#endif

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
    src[0] = sw_open(light_start, light_index, light_value, 3, rows, w, k);
    k = 0;
    for (int r = 0; r < TRIPLE_VIS_ROWS; ++r) {
        float x = vis_weight[TRIPLE_VIS_ROWS * i + r];
        if (x == 0.0f) continue;
        rows[k] = vis_rows[TRIPLE_VIS_ROWS * i + r];
        w[k++] = (float3)(x);
    }
    src[1] = sw_open(vis_start, vis_index, vis_value, 1, rows, w, k);
    k = 0;
    for (int r = 0; r < TRIPLE_BRDF_ROWS; ++r) {
        float3 x = vload3(TRIPLE_BRDF_ROWS * i + r, brdf_weight);
        if (x.x == 0.0f && x.y == 0.0f && x.z == 0.0f) continue;
        rows[k] = brdf_rows[TRIPLE_BRDF_ROWS * i + r];
        w[k++] = x;
    }
    src[2] = sw_open(brdf_start, brdf_index, brdf_value, 1, rows, w, k);
    vstore3(sw_triple(src, root_area, wavelet, tensor), i, out);
}
