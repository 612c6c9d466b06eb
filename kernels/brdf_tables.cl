/* Leaf means over wi of a material's glossy term times cos theta_i, for a grid of local
 * views wo (method triple; pipeline/stages/brdf_tables.py, NumPy twin
 * pipeline/math/brdf_tables.py). f_g = brdf_glossy of kernels/brdf.h: f_F * f_E without
 * rho_s, 1/sr; local frame, wi towards the light.
 *
 * Work-item (n, v): leaf n, view v. out[v * n_leaves + n] = sum over the leaf's SAMPLES
 * directions (level L + r centroids) of weight * f_g(wi, wo_v) * max(cos theta_i, 0)
 * (weights normalised per leaf). */
#include "brdf.h"

__kernel void brdf_leaf_means(__global const float* material,  /* MATERIAL_FLOATS */
                              __global const float* views,     /* n_views * 3 */
                              __global const float* fine,      /* n_leaves * SAMPLES * 3 */
                              __global const float* weight,    /* n_leaves * SAMPLES */
                              const int n_views, const int n_leaves,
                              __global float* out)             /* n_views * n_leaves */
{
    int n = get_global_id(0), v = get_global_id(1);
    if (n >= n_leaves || v >= n_views) return;
    float3 wo = vload3(v, views);
    float acc = 0.0f;
    for (int s = 0; s < SAMPLES; ++s) {
        float3 wi = vload3(n * SAMPLES + s, fine);
        if (wi.z > 0.0f)
            acc += weight[n * SAMPLES + s] * brdf_glossy(material, wi, wo) * wi.z;
    }
    out[(size_t)v * n_leaves + n] = acc;
}
