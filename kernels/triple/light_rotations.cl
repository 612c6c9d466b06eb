/* Leaf means of an environment map seen in the local frames of a frame grid (method
 * triple; pipeline/methods/triple/stages/light_rotations.py, NumPy twin pipeline/methods/triple/light_grid.py).
 *
 * A frame grid entry (phi_j, theta_i, psi_k) is the frame (0, theta_i, psi_k) turned
 * by phi_j about +y (pipeline/methods/triple/frame_grids.py), and turning a direction by phi about
 * +y moves its map column by -phi W / 2 pi. With W a multiple of the grid's n_phi,
 * that is a whole number P = W / n_phi of columns per phi step, so the SAMPLES directions of each leaf (level L + r centroids, local) are mapped to
 * texel coordinates once, in each frame at phi = 0 (light_sample_coords; the stage
 * keeps them across chunks), and reused for every phi. The map is stored phi-major:
 * texel (y, x = k * P + m), P = W / n_phi columns per phi step, at
 * map[(y * P + m) * n_phi + k], so that the texels one sample reads for consecutive
 * phi steps (columns x, x - P, x - 2P, ...) are adjacent in memory.
 *
 * Turning psi by pi is the half turn diag(-1, -1, 1) in local coordinates, which maps
 * leaf n onto leaf partner[n] (pipeline/methods/triple/wavelet_rows.py leaf_permutation): the
 * leaf means of (phi, theta, psi + pi) are those of (phi, theta, psi) permuted. So for
 * an even n_psi the frames given are those with psi < pi (psi_given = n_psi / 2 per
 * theta), and each work-item writes its leaf of both frames.
 *
 * light_sample_coords, work-item (q, b): fine sample q, frame b = i * psi_given + k of
 * the frames at phi = 0 (rows of R, R's columns the frame's tangent, bitangent and
 * normal in world coordinates) for theta_i, psi_k: coords[b * n_fine + q] = the
 * sample's continuous texel coordinates (kernels/envmap.h envmap_texel_coords).
 * light_leaf_means, work-item (n, b): leaf n, frame b. Output the grid entries
 * g = (phi_first + j) * n_theta * n_psi + f, rows f = i * n_psi + k (and f + psi_given
 * when psi_given < n_psi) of each phi, that lie in the span [first, first + span_rows)
 * with first = phi_first * n_theta * n_psi + span_first (a chunk's span starts and
 * ends inside a phi plane: the entries outside it are not computed):
 * out[((g - first) * 3 + c) * n_leaves + n] = sum over the leaf's samples of
 * weight * radiance (weights normalised per leaf).
 * The map comes as float4 texels (RGB and an unused fourth) so that a texel is one
 * aligned load; the lookup is kernels/envmap.h's (bilinear, columns wrapping). */
#include "vectorize.h"
#include "envmap.h"

__kernel void light_sample_coords(__global const float* frames,  /* n_frames * 9 */
                                  __global const float* fine,    /* n_fine * 3 */
                                  const int width, const int height, const int n_frames,
                                  const int n_fine,
                                  __global float2* coords)       /* n_frames * n_fine */
{
    int q = get_global_id(0), b = get_global_id(1);
    if (q >= n_fine || b >= n_frames) return;
    __global const float* r = frames + 9 * b;
    float3 omega = vload3(q, fine);
    float3 d = (float3)(r[0] * omega.x + r[1] * omega.y + r[2] * omega.z,
                        r[3] * omega.x + r[4] * omega.y + r[5] * omega.z,
                        r[6] * omega.x + r[7] * omega.y + r[8] * omega.z);
    coords[(size_t)b * n_fine + q] = envmap_texel_coords(d, width, height);
}

PRT_SCALAR_ITEMS
__kernel void light_leaf_means(__global const float2* coords,  /* n_frames * n_leaves * SAMPLES */
                               __global const float* weight,   /* n_leaves * SAMPLES */
                               __global const float4* map,     /* phi-major, RGB_ */
                               const int width, const int height, const int n_frames,
                               const int n_leaves, const int phi_first, const int phi_count,
                               const int n_phi, const int psi_given, const int n_psi,
                               const int span_first, const int span_rows,
                               __global const int* partner,  /* n_leaves */
                               __global float* out)
{
    int n = get_global_id(0), b = get_global_id(1);
    if (n >= n_leaves || b >= n_frames) return;
    /* per sample and corner: the texel of phi step 0 is at map[base + k], that of step
     * j at map[base + (k - j) mod n_phi]; COLUMNS = P (a constant: no division) */
    int base00[SAMPLES], base01[SAMPLES], base10[SAMPLES], base11[SAMPLES];
    int k0[SAMPLES], k1[SAMPLES];
    float fx[SAMPLES], fy[SAMPLES], w[SAMPLES];
    __global const float2* c = coords + ((size_t)b * n_leaves + n) * SAMPLES;
    for (int s = 0; s < SAMPLES; ++s) {
        float2 xy = c[s];
        float xf = floor(xy.x), yf = floor(xy.y);
        int y = (int)yf, x0 = (int)xf;  /* x0 in [-1, W - 1] */
        if (x0 < 0) x0 += width;
        int m0 = x0 % COLUMNS, m1 = m0 + 1;  /* x0 = k0 P + m0; x1 = x0 + 1, wrapping */
        k0[s] = x0 / COLUMNS;
        k1[s] = k0[s];
        if (m1 == COLUMNS) {
            m1 = 0;
            k1[s] = k0[s] + 1 == n_phi ? 0 : k0[s] + 1;
        }
        int row0 = y * COLUMNS, row1 = min(y + 1, height - 1) * COLUMNS;
        base00[s] = (row0 + m0) * n_phi;
        base01[s] = (row0 + m1) * n_phi;
        base10[s] = (row1 + m0) * n_phi;
        base11[s] = (row1 + m1) * n_phi;
        fx[s] = xy.x - xf;
        fy[s] = xy.y - yf;
        w[s] = weight[n * SAMPLES + s];
    }
    int rows = n_frames / psi_given * n_psi;  /* n_theta * n_psi */
    int f = b / psi_given * n_psi + b % psi_given;
    bool mirrored = psi_given < n_psi;
    for (int j = 0; j < phi_count; ++j) {
        int row = j * rows + f - span_first, partner_row = row + psi_given;
        bool wanted = row >= 0 && row < span_rows;
        bool partner_wanted = mirrored && partner_row >= 0 && partner_row < span_rows;
        if (!wanted && !partner_wanted) continue;
        int step = (phi_first + j) % n_phi;
        float4 acc = (float4)(0.0f);
        for (int s = 0; s < SAMPLES; ++s) {
            int a = k0[s] - step, e = k1[s] - step;
            a += a < 0 ? n_phi : 0;
            e += e < 0 ? n_phi : 0;
            acc += w[s] * ((1.0f - fy[s]) * ((1.0f - fx[s]) * map[base00[s] + a]
                                             + fx[s] * map[base01[s] + e])
                           + fy[s] * ((1.0f - fx[s]) * map[base10[s] + a]
                                      + fx[s] * map[base11[s] + e]));
        }
        size_t at;
        if (wanted) {
            at = ((size_t)row * 3) * n_leaves + n;
            out[at] = acc.x;
            out[at + n_leaves] = acc.y;
            out[at + 2 * n_leaves] = acc.z;
        }
        if (partner_wanted) {
            at = ((size_t)partner_row * 3) * n_leaves + partner[n];
            out[at] = acc.x;
            out[at + n_leaves] = acc.y;
            out[at + 2 * n_leaves] = acc.z;
        }
    }
}
