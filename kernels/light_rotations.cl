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
 * Work-item (n, b): leaf n, frame b of the frames at phi = 0 (rows of R, R's columns
 * the frame's tangent, bitangent and normal in world coordinates). Output for the
 * phi_count phi values from phi_first: out[((j * n_frames + b) * 3 + c) * n_leaves + n]
 * = sum over the leaf's samples of weight * radiance (weights normalised per leaf). */
#include "envmap.h"

__kernel void light_leaf_means(__global const float* frames,  /* n_frames * 9, R row-major */
                               __global const float* fine,    /* n_leaves * SAMPLES * 3 */
                               __global const float* weight,  /* n_leaves * SAMPLES */
                               __global const float* rgb,     /* height * width * 3 */
                               const int width, const int height, const int n_frames,
                               const int n_leaves, const int phi_first, const int phi_count,
                               const int phi_shift,
                               __global float* out)
{
    int n = get_global_id(0), b = get_global_id(1);
    if (n >= n_leaves || b >= n_frames) return;
    __global const float* r = frames + 9 * b;
    float3 r0 = (float3)(r[0], r[1], r[2]), r1 = (float3)(r[3], r[4], r[5]),
           r2 = (float3)(r[6], r[7], r[8]);
    int tx[SAMPLES], ty[SAMPLES];
    float fx[SAMPLES], fy[SAMPLES], w[SAMPLES];
    for (int s = 0; s < SAMPLES; ++s) {
        float3 omega = vload3(n * SAMPLES + s, fine);
        float3 d = (float3)(dot(r0, omega), dot(r1, omega), dot(r2, omega));
        float2 xy = envmap_texel_coords(d, width, height);
        float xf = floor(xy.x), yf = floor(xy.y);
        tx[s] = (int)xf;
        ty[s] = (int)yf;
        fx[s] = xy.x - xf;
        fy[s] = xy.y - yf;
        w[s] = weight[n * SAMPLES + s];
    }
    for (int j = 0; j < phi_count; ++j) {
        int shift = (phi_first + j) * phi_shift;
        float3 acc = (float3)(0.0f);
        for (int s = 0; s < SAMPLES; ++s)
            acc += w[s] * envmap_bilinear(rgb, width, height, tx[s] - shift, ty[s], fx[s],
                                          fy[s]);
        size_t base = ((size_t)(j * n_frames + b) * 3) * n_leaves + n;
        out[base] = acc.x;
        out[base + n_leaves] = acc.y;
        out[base + 2 * n_leaves] = acc.z;
    }
}
