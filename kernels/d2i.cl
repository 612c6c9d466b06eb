/* Method d2i's per-pixel combination (paper 000 eq. 9):
 *   I = direct + kd * (D L) + rho_s * max(0, sum_j c_j(gamma) (T_j L)),
 * from the sparse products D L and T_j L (kernels/sparse_rows.cl). */
#include "brdf.h"

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
