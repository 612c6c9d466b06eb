/* Analytic BRDFs: the same models and formulas as pipeline/math/brdf.py (see its
 * docstring for frames, units, the Fresnel and G terms and the normalizations).
 *
 * Directions are in the local frame (x tangent, y = n × t, z normal), wi towards the
 * light, wo towards the viewer. A material is a row of MATERIAL_FLOATS floats:
 *   [0] model code   [1..3] kd (diffuse albedo)   [4..6] rho_s (specular colour)
 *   [7] gamma        [8] alpha_ratio (anisotropic Ward: alpha_y = ratio * gamma)
 *   [9] cxy [10] cz (Lafortune)   [11] F0 (Schlick)
 *
 * Float precision: lobes are written so that float32 rounding is not raised to the
 * power gamma. With s = wi + wo (the unnormalised half vector), tan^2(delta) =
 * |s_xy|^2 / s_z^2 carries a relative error of a few ulps, and cos^gamma(delta) =
 * exp(-gamma/2 * log1p(tan^2 delta)). Lafortune's lobe base is summed in double where
 * the device has it (1 - x loses all digits in float when x is near 1).
 */
#ifndef PRT_BRDF_H
#define PRT_BRDF_H

#include "inline.h"

#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

#define MATERIAL_FLOATS 16
#define MODEL_LAMBERT 0
#define MODEL_BLINN_PHONG 1
#define MODEL_WARD 2
#define MODEL_WARD_DUER 3
#define MODEL_WARD_ANISOTROPIC 4
#define MODEL_LAFORTUNE 5
#define MODEL_COOK_TORRANCE 6
#define MODEL_ASHIKHMIN_SHIRLEY 7

#define BRDF_PI 3.14159265358979f

#include "fastmath.h"

/* exp and log1p of the lobes; a program may define them first (kernels/triple/brdf_tables.cl:
 * kernels/fastmath.h's, which a CPU vectorises). */
#ifndef BRDF_EXP
#define BRDF_EXP exp
#endif
#ifndef BRDF_LOG1P
#define BRDF_LOG1P log1p
#endif

/* A program built with BRDF_MODEL (a MODEL_* code) fixes the model at build time (no
 * branch on mat[0]; kernels/triple/brdf_tables.cl, one program per model); otherwise the
 * model is read from the material row. */
#ifdef BRDF_MODEL
#define BRDF_MODEL_OF(mat) BRDF_MODEL
#else
#define BRDF_MODEL_OF(mat) ((int)(mat)[0])
#endif

inline float schlick_fresnel(float f0, float v_dot_h) {
    float m = 1.0f - clamp(v_dot_h, 0.0f, 1.0f);
    float m2 = m * m;
    return f0 + (1.0f - f0) * m2 * m2 * m;
}

/* 1 - x for Lafortune's normalised lobe base x = (cxy (lx vx + ly vy) + cz lz vz) / max|C|. */
PRT_INLINE float lafortune_one_minus_x(__global const float* mat, float3 wi, float3 wo) {
#ifdef cl_khr_fp64
    double base = (double)mat[9] * ((double)wi.x * wo.x + (double)wi.y * wo.y)
                  + (double)mat[10] * ((double)wi.z * wo.z);
    return (float)(1.0 - base / fmax(fabs((double)mat[9]), fabs((double)mat[10])));
#else
    return 1.0f - (mat[9] * (wi.x * wo.x + wi.y * wo.y) + mat[10] * wi.z * wo.z)
                  / fmax(fabs(mat[9]), fabs(mat[10]));
#endif
}

/* The glossy part f_F * f_E of the material's model (without rho_s), in 1/sr. */
/* Scalar arithmetic (no float3 temporaries, no dot), the material read before any
 * branch, always inlined: a loop calling it then vectorises across work-items on a CPU
 * device (kernels/triple/brdf_tables.cl). */
PRT_INLINE float brdf_glossy(__global const float* mat, float3 wi, float3 wo) {
    int model = BRDF_MODEL_OF(mat);
    float g = mat[7], ratio = mat[8], f0 = mat[11];  /* loaded before any branch */
    float nl = wi.z, nv = wo.z;
    if (model == MODEL_LAMBERT || nl <= 0.0f || nv <= 0.0f) return 0.0f;
    if (model == MODEL_LAFORTUNE) {
        float u = lafortune_one_minus_x(mat, wi, wo);          /* 1 - x */
        if (u >= 1.0f) return 0.0f;                            /* x <= 0 */
        return (g + 2.0f) / (2.0f * BRDF_PI) * BRDF_EXP(g * BRDF_LOG1P(-fmax(u, 0.0f)));
    }
    float sx = wi.x + wo.x, sy = wi.y + wo.y, sz = wi.z + wo.z;  /* s = wi + wo, scalars */
    float sxy2 = sx * sx + sy * sy;
    float tan2 = sxy2 / (sz * sz);
    if (model == MODEL_BLINN_PHONG)
        return (g + 2.0f) / (2.0f * BRDF_PI) * BRDF_EXP(-0.5f * g * BRDF_LOG1P(tan2));
    if (model == MODEL_WARD || model == MODEL_WARD_DUER || model == MODEL_WARD_ANISOTROPIC) {
        float ax = g, ay = model == MODEL_WARD_ANISOTROPIC ? ratio * g : g;
        float e = (sx * sx / (ax * ax) + sy * sy / (ay * ay)) / (sz * sz);
        float lobe = BRDF_EXP(-e) / (4.0f * BRDF_PI * ax * ay);
        return model == MODEL_WARD_DUER ? lobe / (nl * nv) : lobe * rsqrt(nl * nv);
    }
    float slen = sqrt(sxy2 + sz * sz);
    float vh = (wo.x * sx + wo.y * sy + wo.z * sz) / slen;                 /* wo . s / |s| */
    float fresnel = schlick_fresnel(f0, vh);
    if (model == MODEL_COOK_TORRANCE) {
        float lobe = BRDF_EXP(-tan2 / (g * g));
        if (lobe == 0.0f) return 0.0f;
        float nh = sz / slen;
        float geom = fmin(1.0f, fmin(2.0f * nh * nv / vh, 2.0f * nh * nl / vh));
        float sec2 = 1.0f + tan2;                              /* 1 / cos^2(delta) */
        return lobe / (BRDF_PI * g * g) * geom * fresnel * sec2 * sec2 / (nl * nv);
    }
    if (model == MODEL_ASHIKHMIN_SHIRLEY)
        return (g + 1.0f) / (8.0f * BRDF_PI) * BRDF_EXP(-0.5f * g * BRDF_LOG1P(tan2)) * fresnel
               / (vh * fmax(nl, nv));
    return 0.0f;
}

/* The fixed term f_F(wi, wo) of paper 000 Table 4 (without rho_s; pipeline/math/brdf.py
 * fixed_term): 0 below either horizon and for Lambert. */
PRT_INLINE float brdf_fixed(__global const float* mat, float3 wi, float3 wo) {
    int model = BRDF_MODEL_OF(mat);
    float nl = wi.z, nv = wo.z;
    if (model == MODEL_LAMBERT || nl <= 0.0f || nv <= 0.0f) return 0.0f;
    if (model == MODEL_BLINN_PHONG || model == MODEL_LAFORTUNE) return 1.0f;
    if (model == MODEL_WARD || model == MODEL_WARD_ANISOTROPIC) return 1.0f / sqrt(nl * nv);
    if (model == MODEL_WARD_DUER) return 1.0f / (nl * nv);
    float3 h = normalize(wi + wo);
    float vh = fmax(dot(wo, h), 1e-30f);
    float fresnel = schlick_fresnel(mat[11], vh);
    if (model == MODEL_COOK_TORRANCE) {
        float nh = h.z;
        float geom = fmin(1.0f, fmin(2.0f * nh * nv / vh, 2.0f * nh * nl / vh));
        float nh2 = fmax(nh, 1e-30f) * fmax(nh, 1e-30f);
        return geom * fresnel / (nl * nv * nh2 * nh2);
    }
    if (model == MODEL_ASHIKHMIN_SHIRLEY) return fresnel / (vh * fmax(nl, nv));
    return 0.0f;
}

/* The PCA coordinate x(wi, wo) of the model (pipeline/math/brdf.py coordinate): the
 * angle delta = angle(N, H) in radians (the anisotropic Ward's effective delta_e), or
 * for Lafortune the arc cosine of its lobe base, arccos(x) in [0, pi/2] (computed from
 * 1 - x in double where available, so that x near 1 keeps its digits). */
PRT_INLINE float brdf_coordinate_angle(__global const float* mat, float3 wi, float3 wo) {
    int model = BRDF_MODEL_OF(mat);
    if (model == MODEL_LAFORTUNE) {
        float u = clamp(lafortune_one_minus_x(mat, wi, wo), 0.0f, 1.0f);
        return 2.0f * asin(sqrt(0.5f * u));                  /* arccos(1 - u) */
    }
    float3 s = wi + wo;
    float sy = model == MODEL_WARD_ANISOTROPIC ? s.y / mat[8] : s.y;
    return fast_atan2(sqrt(s.x * s.x + sy * sy), fmax(s.z, 0.0f));
}

/* The full BRDF kd / pi + rho_s * f_F * f_E (RGB, 1/sr); zero below either horizon. */
PRT_INLINE float3 brdf_eval(__global const float* mat, float3 wi, float3 wo) {
    if (wi.z <= 0.0f || wo.z <= 0.0f) return (float3)(0.0f);
    float3 kd = (float3)(mat[1], mat[2], mat[3]);
    float3 ks = (float3)(mat[4], mat[5], mat[6]);
    return kd * (1.0f / BRDF_PI) + ks * brdf_glossy(mat, wi, wo);
}

/* World vector v in the frame (t, n x t, n). */
PRT_INLINE float3 to_local(float3 v, float3 n, float3 t) {
    return (float3)(dot(v, t), dot(v, cross(n, t)), dot(v, n));
}

#endif
