/* The forward spherical Haar transform of many functions at once: the OpenCL twin of
 * pipeline/math/sphwavelet.py WaveletBasis.forward (layout and basis in its docstring).
 *
 * wavelet_forward_level, one launch per level l = L - 1 .. 0, work-item (t, r):
 * triangle t of level l, function r. From the values s_c of function r on t's four
 * children (fine[r * triangles * 4 + 4 t + c], level l + 1; the leaf means for
 * l = L - 1) with child solid angles a_c and wavelet values w_k(c) (basis tables
 * child_area (triangles, 4), wavelet (triangles, 3, 4) of level l):
 *   coeffs[r * n_coeffs + detail_start + 3 t + k] = sum_c a_c w_k(c) s_c   (k = 0, 1, 2)
 *   coarse[r * triangles + t] = sum_c a_c s_c / sum_c a_c                  (t's mean)
 * wavelet_forward_roots, work-item (t, r), after level 0: the scaling coefficients
 *   coeffs[r * n_coeffs + t] = coarse[r * 20 + t] * sqrt(root_area[t]).
 * Scalar loads and sums (no vload4 / dot: PoCL calls those out of line) and no bounds
 * test (the launcher's global size is exact): measured 1.4x less CPU than with them. */

#include "vectorize.h"

PRT_SCALAR_ITEMS
__kernel void wavelet_forward_level(__global const float* fine,
                                    __global const float* child_area,
                                    __global const float* wavelet,
                                    const int triangles, const int detail_start,
                                    const int n_coeffs,
                                    __global float* coarse,
                                    __global float* coeffs)
{
    int t = get_global_id(0), r = get_global_id(1);  /* the global size is exact */
    __global const float* ca = child_area + 4 * t;
    __global const float* s = fine + ((size_t)r * triangles + t) * 4;
    float a0 = ca[0], a1 = ca[1], a2 = ca[2], a3 = ca[3];
    float as0 = a0 * s[0], as1 = a1 * s[1], as2 = a2 * s[2], as3 = a3 * s[3];
    __global float* out = coeffs + (size_t)r * n_coeffs + detail_start + 3 * t;
    __global const float* w = wavelet + 12 * t;
    out[0] = as0 * w[0] + as1 * w[1] + as2 * w[2] + as3 * w[3];
    out[1] = as0 * w[4] + as1 * w[5] + as2 * w[6] + as3 * w[7];
    out[2] = as0 * w[8] + as1 * w[9] + as2 * w[10] + as3 * w[11];
    coarse[(size_t)r * triangles + t] = (as0 + as1 + as2 + as3) / (a0 + a1 + a2 + a3);
}

__kernel void wavelet_forward_roots(__global const float* coarse,
                                    __global const float* root_area,
                                    const int n_coeffs,
                                    __global float* coeffs)
{
    int t = get_global_id(0), r = get_global_id(1);
    if (t >= 20) return;
    coeffs[(size_t)r * n_coeffs + t] = coarse[r * 20 + t] * sqrt(root_area[t]);
}
