/* Spherical Gaussians: the OpenCL twin of pipeline/math/sg.py (read its docstring for
 * the lobe G(w; mu, lam) = exp(lam (mu.w - 1)), lam = 1/sigma^2, and the float32-stable
 * forms used here). All directions are unit float3; lam >= 0.
 *
 * The prefiltered environment stack (sg_env_integral) is one float buffer holding the
 * levels' lat-long maps back to back (H_l * W_l * 3 floats each, envmap.h's layout)
 * and a table of 3 ints per level: the level's first texel, its width, its height.
 * Level l is the map convolved (normalised) with an SG of sigma_l = sigma0 ratio^l. */
#ifndef PRT_SG_H
#define PRT_SG_H

#include "inline.h"

#include "envmap.h"

#define SG_TWO_PI 6.28318530717959f

/* G(w; mu, lam) = exp(-lam |w - mu|^2 / 2): no cancellation near the peak. */
PRT_INLINE float sg_eval(float3 w, float3 mu, float lam) {
    float3 d = w - mu;
    return exp(-0.5f * lam * dot(d, d));
}

/* (1 - e^{-2 lam}) / lam = -expm1(-2 lam) / lam, 2 at lam = 0. */
inline float sg_integral_factor(float lam) {
    return lam > 0.0f ? -expm1(-2.0f * lam) / lam : 2.0f;
}

/* Integral of G over the sphere: 2 pi (1 - e^{-2 lam}) / lam (sr). */
inline float sg_integral(float lam) { return SG_TWO_PI * sg_integral_factor(lam); }

/* G_a G_b = scale * G(w; *mu, *lam): u = la mu_a + lb mu_b, r = |u|, mean u/r, sharpness
 * r, scale = exp(-la lb |mu_a - mu_b|^2 / (r + la + lb)) (= e^{r - la - lb}). Returns
 * scale. Where r = 0 (equal antipodal lobes) the mean is mu_a and the sharpness 0. */
PRT_INLINE float sg_product(float3 mu_a, float la, float3 mu_b, float lb, float3* mu,
                        float* lam) {
    float3 u = la * mu_a + lb * mu_b;
    float r = length(u);
    float3 d = mu_a - mu_b;
    *mu = r > 0.0f ? u / r : mu_a;
    *lam = r;
    return exp(-la * lb * dot(d, d) / fmax(r + la + lb, 1e-30f));
}

/* Inner product of two lobes, the integral of G_a G_b over the sphere (sr). */
PRT_INLINE float sg_inner(float3 mu_a, float la, float3 mu_b, float lb) {
    float3 mu;
    float lam;
    float scale = sg_product(mu_a, la, mu_b, lb, &mu, &lam);
    return scale * sg_integral(lam);
}

/* Bilinear radiance of stack level l at the map coordinates (u, v) in [0, 1) x [0, 1]
 * (envmap.h's texel coordinates X = u W_l - 1/2, Y = v (H_l - 1)). */
PRT_INLINE float3 sg_level_radiance(__global const float* stack, __global const int* level_info,
                                int l, float u, float v) {
    int width = level_info[3 * l + 1], height = level_info[3 * l + 2];
    float x = u * width - 0.5f, y = v * (height - 1);
    float x0 = floor(x), y0 = floor(y);
    return envmap_bilinear(stack + 3 * level_info[3 * l], width, height, (int)x0, (int)y0,
                           x - x0, y - y0);
}

/* Integral of weight * G(w; mu, lam) against the environment, mu in the map's frame:
 * weight * (integral of G) * P(mu, sigma), P bilinear in direction on the two levels
 * around f = log(sigma / sigma0) / log(ratio) (clamped to [0, levels - 1]) and linear
 * in f between them. log_sigma0 = log(sigma0), inv_log_ratio = 1 / log(ratio). The map
 * coordinates (u, v) of mu are computed once for both levels. */
PRT_INLINE float3 sg_env_integral(__global const float* stack, __global const int* level_info,
                              int levels, float log_sigma0, float inv_log_ratio,
                              float3 mu, float lam, float3 weight) {
    float f = (-0.5f * log(fmax(lam, 1e-30f)) - log_sigma0) * inv_log_ratio;
    f = clamp(f, 0.0f, (float)(levels - 1));
    int lo = min((int)floor(f), max(levels - 2, 0));
    int hi = min(lo + 1, levels - 1);
    float t = f - (float)lo;
    float u = atan2(mu.x, -mu.z) * (0.5f / ENVMAP_PI);
    u -= floor(u);
    float v = acos(clamp(mu.y, -1.0f, 1.0f)) * (1.0f / ENVMAP_PI);
    float3 a = sg_level_radiance(stack, level_info, lo, u, v);
    float3 b = sg_level_radiance(stack, level_info, hi, u, v);
    return weight * sg_integral(lam) * ((1.0f - t) * a + t * b);
}

#endif
