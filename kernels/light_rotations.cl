/* Leaf means of an environment map seen in the local frames of a frame grid (method
 * triple; pipeline/stages/light_rotations.py, NumPy twin pipeline/math/light_grid.py).
 *
 * A frame grid entry (phi_j, theta_i, psi_k) is the frame (0, theta_i, psi_k) turned
 * by phi_j about +y (pipeline/math/frame_grids.py), and turning a direction by phi about
 * +y moves its map column by -phi W / 2 pi. With W a multiple of the grid's n_phi,
 * that is a whole number of columns per phi step (phi_shift), so
 * each work-item maps its leaf's SAMPLES directions (level L + r centroids, local) to
 * texel coordinates once, in its frame at phi = 0, and reuses them for every phi.
 *
 * Turning psi by pi is the half turn diag(-1, -1, 1) in local coordinates, which maps
 * leaf n onto leaf partner[n] (pipeline/math/wavelet_rows.py leaf_permutation): the
 * leaf means of (phi, theta, psi + pi) are those of (phi, theta, psi) permuted. So for
 * an even n_psi the frames given are those with psi < pi (psi_given = n_psi / 2 per
 * theta), and each work-item writes its leaf of both frames.
 *
 * Work-item (n, b): leaf n, frame b = i * psi_given + k of the frames at phi = 0
 * (rows of R, R's columns the frame's tangent, bitangent and normal in world
 * coordinates) for theta_i, psi_k. Output for the phi_count phi values from phi_first,
 * rows f = i * n_psi + k (and f + psi_given when psi_given < n_psi) of each phi:
 * out[((j * n_theta * n_psi + f) * 3 + c) * n_leaves + n] = sum over the leaf's
 * samples of weight * radiance (weights normalised per leaf).
 * The map comes as float4 texels (RGB and an unused fourth) so that a texel is one
 * aligned load; the lookup is kernels/envmap.h's (texel coordinates, bilinear). */
#include "envmap.h"

/* envmap_bilinear on float4 texels (H * W, the fourth unused): columns x0 in [-W, W)
 * (wrapping) and x0 + 1, rows starting at texels row0 and row1 (the clamped y0 + 1). */
inline float4 texel_bilinear(__global const float4* map, int width, int x0, int row0,
                             int row1, float fx, float fy) {
    if (x0 < 0) x0 += width;
    int x1 = x0 + 1 == width ? 0 : x0 + 1;
    return (1.0f - fy) * ((1.0f - fx) * map[row0 + x0] + fx * map[row0 + x1])
           + fy * ((1.0f - fx) * map[row1 + x0] + fx * map[row1 + x1]);
}

__kernel void light_leaf_means(__global const float* frames,  /* n_frames * 9, R row-major */
                               __global const float* fine,    /* n_leaves * SAMPLES * 3 */
                               __global const float* weight,  /* n_leaves * SAMPLES */
                               __global const float4* map,    /* height * width, RGB_ */
                               const int width, const int height, const int n_frames,
                               const int n_leaves, const int phi_first, const int phi_count,
                               const int phi_shift, const int psi_given, const int n_psi,
                               __global const int* partner,  /* n_leaves */
                               __global float* out)
{
    int n = get_global_id(0), b = get_global_id(1);
    if (n >= n_leaves || b >= n_frames) return;
    __global const float* r = frames + 9 * b;
    float3 r0 = (float3)(r[0], r[1], r[2]), r1 = (float3)(r[3], r[4], r[5]),
           r2 = (float3)(r[6], r[7], r[8]);
    int tx[SAMPLES], row0[SAMPLES], row1[SAMPLES];
    float fx[SAMPLES], fy[SAMPLES], w[SAMPLES];
    for (int s = 0; s < SAMPLES; ++s) {
        float3 omega = vload3(n * SAMPLES + s, fine);
        float3 d = (float3)(dot(r0, omega), dot(r1, omega), dot(r2, omega));
        float2 xy = envmap_texel_coords(d, width, height);
        float xf = floor(xy.x), yf = floor(xy.y);
        int y = (int)yf;
        tx[s] = (int)xf;  /* in [-1, W - 1] */
        row0[s] = y * width;
        row1[s] = min(y + 1, height - 1) * width;
        fx[s] = xy.x - xf;
        fy[s] = xy.y - yf;
        w[s] = weight[n * SAMPLES + s];
    }
    for (int j = 0; j < phi_count; ++j) {
        int shift = ((phi_first + j) * phi_shift) % width;  /* tx - shift >= -W */
        float4 acc = (float4)(0.0f);
        for (int s = 0; s < SAMPLES; ++s)
            acc += w[s] * texel_bilinear(map, width, tx[s] - shift, row0[s], row1[s],
                                         fx[s], fy[s]);
        int rows = n_frames / psi_given * n_psi;  /* n_theta * n_psi */
        int f = b / psi_given * n_psi + b % psi_given;
        size_t base = ((size_t)(j * rows + f) * 3) * n_leaves + n;
        out[base] = acc.x;
        out[base + n_leaves] = acc.y;
        out[base + 2 * n_leaves] = acc.z;
        if (psi_given < n_psi) {
            base = ((size_t)(j * rows + f + psi_given) * 3) * n_leaves + partner[n];
            out[base] = acc.x;
            out[base + n_leaves] = acc.y;
            out[base + 2 * n_leaves] = acc.z;
        }
    }
}
