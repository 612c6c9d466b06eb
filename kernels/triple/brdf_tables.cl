/* Leaf means over wi of a material's glossy term times cos theta_i, for a grid of local
 * views wo (method triple; pipeline/methods/triple/stages/brdf_tables.py, NumPy twin
 * pipeline/methods/triple/brdf_tables.py). f_g = brdf_glossy of kernels/brdf.h: f_F * f_E without
 * rho_s, 1/sr; local frame, wi towards the light. Built once per model (BRDF_MODEL), its
 * exp / log1p kernels/fastmath.h's.
 *
 * brdf_leaf_means, work-item (k, v): upper leaf k (leaf[k], one with a sample above the
 * horizon; the other leaves' means are 0 and the launcher zero-fills them), view v. The
 * sample arrays are padded (zero weights and directions) to the global size, a multiple
 * of the work-group size LOCAL, and only the store is guarded: PoCL then vectorises the
 * work-item loop (8 leaves per AVX2 instruction; an early return, a conditional load
 * or a libm call each stopped it).
 * out[v * n_leaves + leaf[k]] = sum over the leaf's SAMPLES directions (level L + r
 * centroids) of weight * f_g(wi, wo_v) * max(cos theta_i, 0) (weights normalised per
 * leaf; brdf_glossy is 0 for cos theta_i <= 0). The samples are laid out coordinate- and
 * sample-major, fine[(c * SAMPLES + s) * padded + k], so neighbouring work-items read
 * neighbouring floats.
 *
 * brdf_mirror_views, work-item (t, j): the leaf means of view (phi_j, theta_t) are
 * those of view (phi_source[j], theta_t) with leaves permuted (a reflection of wi and
 * wo together; pipeline/methods/triple/stages/brdf_tables.py view_leaf_means):
 * out[(j, t, n)] = base[(source[j], t, perm[j, n])] for every leaf n. A copy: exact.
 * One row per work-item (a loop over n) measured 3.5x less CPU than a work-item per
 * (n, t, j) with a bounds test (0.063 against 0.223 CPU-s for 8192 rows of 5120). */
#include "fastmath.h"
#define BRDF_EXP fast_exp
#define BRDF_LOG1P fast_log1p
#include "brdf.h"

__kernel void brdf_leaf_means(__global const float* material,  /* MATERIAL_FLOATS */
                              __global const float* views,     /* n_views * 3 */
                              __global const float* fine,      /* 3 * SAMPLES * padded */
                              __global const float* weight,    /* SAMPLES * padded */
                              __global const int* leaf,        /* padded */
                              const int n_upper, const int padded, const int n_leaves,
                              __global float* out)             /* n_views * n_leaves */
{
    int k = get_global_id(0), v = get_global_id(1);  /* k < n_upper rounded up to LOCAL */
    float3 wo = (float3)(views[3 * v], views[3 * v + 1], views[3 * v + 2]);
    float acc = 0.0f;
#pragma unroll  /* the work-item loop PoCL wraps round this body is then the innermost */
    for (int s = 0; s < SAMPLES; ++s) {
        float3 wi = (float3)(fine[s * padded + k], fine[(SAMPLES + s) * padded + k],
                             fine[(2 * SAMPLES + s) * padded + k]);
        acc += weight[s * padded + k] * brdf_glossy(material, wi, wo) * wi.z;
    }
    if (k < n_upper) out[(size_t)v * n_leaves + leaf[k]] = acc;
}

__kernel void brdf_mirror_views(__global const float* base,   /* (quarter + 1, n_theta, N) */
                                __global const int* source,   /* (n_phi,) */
                                __global const int* perm,     /* (n_phi, N) */
                                const int n_theta, const int n_leaves,
                                __global float* out)          /* (n_phi, n_theta, N) */
{
    int t = get_global_id(0), j = get_global_id(1);  /* the global size is exact */
    __global const float* from = base + ((size_t)source[j] * n_theta + t) * n_leaves;
    __global const int* p = perm + (size_t)j * n_leaves;
    __global float* to = out + ((size_t)j * n_theta + t) * n_leaves;
    for (int n = 0; n < n_leaves; ++n) to[n] = from[p[n]];
}
