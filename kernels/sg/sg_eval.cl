/* Spherical Gaussian formulas at arrays of lobes: the OpenCL side of the NumPy/OpenCL
 * agreement tests of kernels/sg/sg.h (tests/test_sg.py). One work-item per item i. */
#include "sg.h"

/* Per pair of lobes a, b (means n * 3, sharpness n) and direction w (n * 3):
 * out[8 i ..] = G_a(w), integral of G_a, <G_a, G_b>, product scale, product sharpness,
 * product mean (3). */
__kernel void sg_formulas(__global const float* mu_a, __global const float* lam_a,
                          __global const float* mu_b, __global const float* lam_b,
                          __global const float* w, const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 ma = vload3(i, mu_a), mb = vload3(i, mu_b);
    float la = lam_a[i], lb = lam_b[i];
    float3 mu;
    float lam;
    float scale = sg_product(ma, la, mb, lb, &mu, &lam);
    __global float* o = out + 8 * i;
    o[0] = sg_eval(vload3(i, w), ma, la);
    o[1] = sg_integral(la);
    o[2] = sg_inner(ma, la, mb, lb);
    o[3] = scale;
    o[4] = lam;
    vstore3(mu, 0, o + 5);
}

/* Environment integrals of n lobes (map-space means n * 3, sharpness n, RGB weights
 * n * 3) against a prefiltered stack; out n * 3. */
__kernel void sg_env(__global const float* stack, __global const int* level_info,
                     const int levels, const float log_sigma0, const float inv_log_ratio,
                     __global const float* mu, __global const float* lam,
                     __global const float* weight, const int n, __global float* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    vstore3(sg_env_integral(stack, level_info, levels, log_sigma0, inv_log_ratio,
                            vload3(i, mu), lam[i], vload3(i, weight)), i, out);
}
