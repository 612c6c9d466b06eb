/* exp, log1p and atan2 in float32 from additions, multiplications and bit operations
 * only, so that a CPU device vectorises them across work-items (PoCL calls its scalar
 * libm for exp / log1p: measured ~45 ns per exp + log1p pair, 10x a Blinn-Phong lobe's other
 * arithmetic, and an out-of-line call stops the vectoriser; so no builtin is called
 * here). Cephes' expf / logf polynomials (S. L. Moshier); relative error a few
 * ulp (tests/test_triple_tables.py: against NumPy's float64, tolerance 4e-7). Used by
 * kernels/triple/brdf_tables.cl through brdf.h's BRDF_EXP / BRDF_LOG1P. */
#ifndef PRT_FASTMATH_H
#define PRT_FASTMATH_H

#include "inline.h"

/* e^x: x = n ln2 + r, |r| <= ln2 / 2 (ln2 split in two for an exact n ln2), e^r by a
 * degree-7 polynomial, 2^n from the exponent bits (two factors, so n = 128 fits). 0 below -87.3 (under the smallest
 * normal float), +inf above 88.7. */
PRT_INLINE float fast_exp(float x) {
    float t = x * 1.44269504088896341f + 0.5f;
    int i = (int)t;                                      /* n = floor(t), no libm call */
    i -= t < (float)i ? 1 : 0;
    float n = (float)i;
    float r = x - n * 0.693359375f;
    r = r - n * -2.12194440e-4f;
    float z = r * r;
    float p = ((((1.9875691500e-4f * r + 1.3981999507e-3f) * r + 8.3334519073e-3f) * r
               + 4.1665795894e-2f) * r + 1.6666665459e-1f) * r + 5.0000001201e-1f;
    float y = p * z + r + 1.0f;
    int e = i < -126 ? -126 : i > 128 ? 128 : i;
    int h = e >> 1;                                      /* 2^e = 2^h 2^(e-h), both normal */
    float out = y * as_float((h + 127) << 23) * as_float((e - h + 127) << 23);
    out = x < -87.33654f ? 0.0f : out;
    return x > 88.72283f ? INFINITY : out;
}

/* ln(u) for a normal u > 0: u = m 2^k, m in [sqrt(1/2), sqrt(2)), ln(m) = t - t^2/2 +
 * t^3 P(t) with t = m - 1. */
PRT_INLINE float fast_log(float u) {
    int bits = as_int(u);
    int k = ((bits >> 23) & 0xff) - 126;                 /* u = m' 2^k, m' in [1/2, 1) */
    float m = as_float((bits & 0x007fffff) | 0x3f000000);
    bool low = m < 0.707106781186547524f;
    k -= low ? 1 : 0;
    float t = (low ? m + m : m) - 1.0f;
    float z = t * t;
    float p = ((((((((7.0376836292e-2f * t - 1.1514610310e-1f) * t + 1.1676998740e-1f) * t
                   - 1.2420140846e-1f) * t + 1.4249322787e-1f) * t - 1.6668057665e-1f) * t
                 + 2.0000714765e-1f) * t - 2.4999993993e-1f) * t + 3.3333331174e-1f);
    float kf = (float)k;
    float y = t * z * p + kf * -2.12194440e-4f - 0.5f * z;
    return t + y + kf * 0.693359375f;
}

/* ln(1 + x) for x > -1, to a few ulp also for small |x|: with u = fl(1 + x),
 * ln(1 + x) = ln(u) · x / (u − 1) (Goldberg's correction for the rounding of u);
 * x itself where u rounds to 1; +inf for x = +inf. */
PRT_INLINE float fast_log1p(float x) {
    float u = 1.0f + x;
    float d = u - 1.0f;
    float out = d == 0.0f ? x : fast_log(u) * (x / d);
    return x == INFINITY ? x : out;
}

/* atan2(y, x) in [−π, π] by a minimax polynomial for atan on [0, 1]: within 1e-6 rad
 * of the true angle, relative error ≤ 1e-6 for small angles (tests/test_fastmath.py),
 * several times cheaper than PoCL's atan2/acos (measured: 50 of 124 ns per pair of the
 * transfer kernel); atan2(0, 0) = 0. Used by kernels/triple/triple_lookup.h and brdf.h's PCA
 * coordinate. */
PRT_INLINE float fast_atan2(float y, float x) {
    float ax = fabs(x), ay = fabs(y);
    float hi = fmax(ax, ay);
    float a = hi > 0.0f ? fmin(ax, ay) / hi : 0.0f;
    float s = a * a;
    float r = ((((-0.0040540580f * s + 0.0218612288f) * s - 0.0559098861f) * s
                + 0.0964200441f) * s - 0.1390853351f) * s;
    r = ((r + 0.1994653599f) * s - 0.3332985605f) * s * a + a;
    if (ay > ax) r = 1.57079632679f - r;
    if (x < 0.0f) r = 3.14159265358979f - r;
    return y < 0.0f ? -r : r;
}

#endif
