/* Deterministic per-pixel random numbers; the same formulas as pipeline/math/sampling.py. */
#ifndef PRT_SAMPLING_H
#define PRT_SAMPLING_H

/* Wellons' lowbias32 integer hash. */
inline uint lowbias32(uint x) {
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

/* Uniform in [0, 1), exact in float: the top 24 bits of the hash / 2^24. */
inline float sample_uniform(uint pixel, uint light, uint sample, uint dim) {
    uint inner = lowbias32(light * 0x85ebca6bU + sample * 0xc2b2ae35U + dim);
    uint h = lowbias32(pixel * 0x9e3779b1U + inner);
    return (float)(h >> 8) * (1.0f / 16777216.0f);
}

/* Sample s of an m x m jittered grid over [0, 1)^2; cell (s mod m, s div m). */
inline float2 stratified_square(uint pixel, uint light, uint s, uint m) {
    float inv = 1.0f / (float)m;
    float u = ((float)(s % m) + sample_uniform(pixel, light, s, 0)) * inv;
    float v = ((float)(s / m) + sample_uniform(pixel, light, s, 1)) * inv;
    return (float2)(u, v);
}

#endif
