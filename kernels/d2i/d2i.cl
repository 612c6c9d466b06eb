/* Method d2i's per-pixel combination (paper 000 eq. 9):
 *   I = direct + kd * (D L) + rho_s * max(0, sum_j c_j(gamma) (T_j L)),
 * from the sparse products D L and T_j L (kernels/d2i/sparse_rows.cl). */
#include "brdf.h"

/* One work-item per pixel. glossy_first[p] is the pixel's first row in tl (-1 for none),
 * glossy_rows[p] its row count; coefficients holds c(gamma) per material (row stride
 * rmax, c_0 = 1 for b0). Negative glossy sums (ringing of the truncated PCA basis) are
 * clamped to 0 per channel, and so is the pixel (radiance is never negative; the
 * truncated Haar rows of D L can dip a hair below 0 where little light arrives: −2e-6
 * on an open triangle 1e4 units wide). */
__kernel void combine(__global const float* direct, __global const float4* dl,
                      __global const int* material_id, __global const float* materials,
                      __global const int* glossy_first, __global const int* glossy_rows,
                      __global const float4* tl, __global const float* coefficients,
                      const int rmax, const int npix, __global float* out)
{
    int p = get_global_id(0);
    if (p >= npix) return;
    float3 rgb = vload3(p, direct);
    int m = material_id[p];
    if (m >= 0) {
        __global const float* mat = materials + m * MATERIAL_FLOATS;
        rgb += (float3)(mat[1], mat[2], mat[3]) * dl[p].xyz;
        int first = glossy_first[p];
        if (first >= 0) {
            float3 g = (float3)(0.0f);
            for (int j = 0; j < glossy_rows[p]; ++j)
                g += coefficients[m * rmax + j] * tl[first + j].xyz;
            rgb += (float3)(mat[4], mat[5], mat[6]) * fmax(g, (float3)(0.0f));
        }
    }
    vstore3(fmax(rgb, (float3)(0.0f)), p, out);
}

/* Per item (a pixel's D L, a gather sample's Ms product) its own row's product, from the
 * products of rows transformed across blocks of n items (pipeline/methods/d2i/blocks.py, unblock is
 * the NumPy twin): out[i] = sum_q transform[q][slot[i]] * blocks[block_of[i] * n + q],
 * transform (n x n, row-major) orthonormal. */
__kernel void unblock(__global const float4* blocks, __global const float* transform,
                      const int n, __global const int* block_of, __global const int* slot,
                      const int count, __global float4* out)
{
    int i = get_global_id(0);
    if (i >= count) return;
    __global const float4* rows = blocks + block_of[i] * n;
    __global const float* column = transform + slot[i];
    float4 sum = (float4)(0.0f);
    for (int q = 0; q < n; ++q)
        sum += column[q * n] * rows[q];
    out[i] = sum;
}

/* ---- The bounce loop on the device (pipeline/methods/d2i/render.py, gather_radiance) ----
 * Per bounce: the radiance vector [W (|A| ⊙ L); |A| ⊙ L] of the gathers' radiance L
 * (haar_input, then haar_level once per level: pipeline/math/haar.py's orthonormal
 * transform in its standard layout), the sparse product with Ms (sparse_rows.cl), and
 * bounce_step; the host reads a few sums per work-group to decide when to stop. */

#define D2I_SQRT_HALF 0.70710678118654752f
#define D2I_GROUP 64  /* bounce_step's work-group size (its reduction) */
#ifndef HAAR_BLOCK     /* haar_blocks' largest work-group (d2i.py HAAR_BLOCK passes it) */
#define HAAR_BLOCK 256
#endif

/* scaling[i] = |A_i| L_i for i < g, 0 up to the Haar length n (a power of two);
 * vec[n + i] = |A_i| L_i. */
__kernel void haar_input(__global const float4* radiance, __global const float* area,
                         const int g, const int n, __global float4* vec,
                         __global float4* scaling)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float4 x = i < g ? area[i] * radiance[i] : (float4)(0.0f);
    scaling[i] = x;
    if (i < g) vec[n + i] = x;
    if (n == 1) vec[0] = x;  /* a one-entry transform is the entry (no haar_blocks pass) */
}

/* HAAR_BLOCK levels of the transform at once: work-group b (size B = min(HAAR_BLOCK,
 * length), a power of two) takes the scaling coefficients src[b·B, (b + 1)·B) of the
 * current `length` through log2 B levels in local memory, writing each level's wavelets
 * where the level-by-level transform puts them (level half-length h: vec[h + b·B/2^k +
 * i]) and its one remaining scaling coefficient to dst[b]; the pass that starts with a
 * single block (length = B) also writes vec[0]. A 2^14-entry transform is 2 launches
 * instead of 14. */
__kernel void haar_blocks(__global const float4* src, const int length,
                          __global float4* dst, __global float4* vec)
{
    __local float4 block[HAAR_BLOCK];
    int i = get_local_id(0), b = get_group_id(0), size = get_local_size(0);
    block[i] = src[b * size + i];
    int h = length;  /* the level's global half-length (wavelets at vec[h, 2h)) */
    for (int m = size / 2; m >= 1; m /= 2) {
        h /= 2;
        barrier(CLK_LOCAL_MEM_FENCE);
        float4 a = (float4)(0.0f), c = a;
        if (i < m) {
            a = block[2 * i];
            c = block[2 * i + 1];
            vec[h + b * m + i] = (a - c) * D2I_SQRT_HALF;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        if (i < m) block[i] = (a + c) * D2I_SQRT_HALF;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (i == 0) {
        dst[b] = block[0];
        if (length == size) vec[0] = block[0];
    }
}

/* L_{n+1} = kd ⊙ (Ms^w · W (|A| ⊙ L_n)) from the product `ms` (g float4); `bounce` holds
 * L_n and is overwritten with L_{n+1}; total += L_{n+1}. Per work-group, into
 * partial[2·group], partial[2·group + 1]: (Σ |A| L_{n+1} per channel, Σ |L_{n+1}|²)
 * and (Σ |A| L_n per channel, Σ |total|²) — the bounce's power, the previous one's, and
 * the norms the stopping rule compares. */
__kernel void bounce_step(__global const float4* ms, __global const int* material,
                          __global const float4* albedo, __global const float* area,
                          const int g, __global float4* bounce, __global float4* total,
                          __global float4* partial)
{
    __local float4 sums[2][D2I_GROUP];
    int i = get_global_id(0), l = get_local_id(0);
    float4 now = (float4)(0.0f), before = (float4)(0.0f);
    if (i < g) {
        float4 previous = bounce[i];
        float4 next = albedo[material[i]] * (float4)(ms[i].xyz, 0.0f);
        float4 sum = total[i] + next;
        bounce[i] = next;
        total[i] = sum;
        now = (float4)(area[i] * next.xyz, dot(next, next));
        before = (float4)(area[i] * previous.xyz, dot(sum, sum));
    }
    sums[0][l] = now;
    sums[1][l] = before;
    for (int step = D2I_GROUP / 2; step > 0; step >>= 1) {
        barrier(CLK_LOCAL_MEM_FENCE);
        if (l < step) {
            sums[0][l] += sums[0][l + step];
            sums[1][l] += sums[1][l + step];
        }
    }
    if (l == 0) {
        partial[2 * get_group_id(0)] = sums[0][0];
        partial[2 * get_group_id(0) + 1] = sums[1][0];
    }
}

/* total += factor ⊙ bounce (the closed-form tail of a settled series; factor.w = 0). */
__kernel void add_scaled(__global const float4* bounce, const float4 factor, const int g,
                         __global float4* total)
{
    int i = get_global_id(0);
    if (i >= g) return;
    total[i] += factor * bounce[i];
}
