/* Method d2i's run-time products (paper 000 eq. 9, 17): sparse Haar rows against a
 * radiance vector in the Haar domain, and the per-pixel combination
 *   I = direct + kd * (D L) + rho_s * max(0, sum_j c_j(gamma) (T_j L)).
 * Rows are CSR (offsets[r] .. offsets[r + 1] into index / value); radiance is float4
 * (RGB, w unused) per Haar coefficient. */
#include "brdf.h"

/* out[r] = sum over row r of value * radiance[index]  (one work-item per row).
 * Four independent partial sums, four entries per step: one accumulator would chain
 * every add on the previous one (latency-bound, about half the speed on PoCL's CPU
 * device); so the loop keeps several loads in flight and runs at the rows' streaming
 * rate (benchmarks/bench_d2i.py). Written as mul + add: fma() is slower on PoCL. */
__kernel void sparse_rows(__global const int* offsets, __global const int* index,
                          __global const float* value, __global const float4* radiance,
                          const int rows, __global float4* out)
{
    int r = get_global_id(0);
    if (r >= rows) return;
    float4 a0 = (float4)(0.0f), a1 = a0, a2 = a0, a3 = a0;
    int e = offsets[r], end = offsets[r + 1];
    for (; e + 4 <= end; e += 4) {
        a0 += value[e] * radiance[index[e]];
        a1 += value[e + 1] * radiance[index[e + 1]];
        a2 += value[e + 2] * radiance[index[e + 2]];
        a3 += value[e + 3] * radiance[index[e + 3]];
    }
    for (; e < end; ++e) a0 += value[e] * radiance[index[e]];
    out[r] = (a0 + a1) + (a2 + a3);
}

/* One work-item per pixel. glossy_first[p] is the pixel's first row in tl (-1 for none),
 * glossy_rows[p] its row count; coefficients holds c(gamma) per material (row stride
 * rmax, c_0 = 1 for b0). Negative glossy sums (ringing of the truncated PCA basis) are
 * clamped to 0 per channel. */
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
    vstore3(rgb, p, out);
}
