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
 *   coeffs[r * n_coeffs + t] = coarse[r * 20 + t] * sqrt(root_area[t]). */

__kernel void wavelet_forward_level(__global const float* fine,
                                    __global const float* child_area,
                                    __global const float* wavelet,
                                    const int triangles, const int detail_start,
                                    const int n_coeffs,
                                    __global float* coarse,
                                    __global float* coeffs)
{
    int t = get_global_id(0), r = get_global_id(1);
    if (t >= triangles) return;
    float4 a = vload4(t, child_area);
    float4 as = a * vload4((size_t)r * triangles + t, fine);
    __global float* out = coeffs + (size_t)r * n_coeffs + detail_start + 3 * t;
    for (int k = 0; k < 3; ++k)
        out[k] = dot(as, vload4(3 * t + k, wavelet));
    coarse[(size_t)r * triangles + t] = (as.x + as.y + as.z + as.w) / (a.x + a.y + a.z + a.w);
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
