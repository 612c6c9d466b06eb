/* Latitude-longitude environment maps: the OpenCL twin of pipeline/math/envmap.py
 * (EnvironmentMap.radiance; Mitsuba 3's mapping, world +y up). A map-space unit
 * direction d = (x, y, z) looks up
 *
 *     u = atan2(x, -z) / 2 pi  (mod 1),   v = arccos(y) / pi,
 *
 * at the continuous texel coordinates X = u W - 1/2 (column j centred at X = j,
 * wrapping) and Y = v (H - 1) (row 0 the +y pole, row H - 1 the -y pole), bilinearly.
 * The map is H * W * 3 floats, row-major RGB radiance (W/(m^2 sr)); the caller applies
 * the light's scale. A map rotated by an angle about +y is looked up at
 * envmap_from_world(d_world, cos angle, sin angle).
 */
#ifndef PRT_ENVMAP_H
#define PRT_ENVMAP_H

#include "inline.h"

#define ENVMAP_PI 3.14159265358979f

/* Map-space direction of world direction d for a map rotated by the angle whose cosine
 * and sine are c, s about +y: rotation_y(-angle) d (envmap.py: d @ to_world). */
PRT_INLINE float3 envmap_from_world(float3 d, float c, float s) {
    return (float3)(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
}

/* Map-space direction of world direction d for a map turned by any rotation R:
 * Rᵀ d, with m the 9 floats of Rᵀ, row-major (envmap.py: d @ to_world). */
PRT_INLINE float3 envmap_into_map(float3 d, __global const float* m) {
    return (float3)(m[0] * d.x + m[1] * d.y + m[2] * d.z, m[3] * d.x + m[4] * d.y + m[5] * d.z,
                    m[6] * d.x + m[7] * d.y + m[8] * d.z);
}

/* Continuous texel coordinates (X, Y) of a map-space unit direction. */
PRT_INLINE float2 envmap_texel_coords(float3 d, int width, int height) {
    float u = atan2(d.x, -d.z) * (0.5f / ENVMAP_PI);
    u -= floor(u);
    float v = acos(clamp(d.y, -1.0f, 1.0f)) * (1.0f / ENVMAP_PI);
    return (float2)(u * width - 0.5f, v * (height - 1));
}

/* Bilinear radiance between the texels (x0, y0) .. (x0 + 1, y0 + 1) with weights
 * fx, fy of the second ones; x0 wraps (any integer), y0 in [0, H - 1] clamps. */
PRT_INLINE float3 envmap_bilinear(__global const float* rgb, int width, int height, int x0,
                              int y0, float fx, float fy) {
    x0 %= width;
    if (x0 < 0) x0 += width;
    int x1 = x0 + 1 == width ? 0 : x0 + 1;
    int y1 = min(y0 + 1, height - 1);
    float3 a = vload3(y0 * width + x0, rgb), b = vload3(y0 * width + x1, rgb);
    float3 c = vload3(y1 * width + x0, rgb), d = vload3(y1 * width + x1, rgb);
    return (1.0f - fy) * ((1.0f - fx) * a + fx * b) + fy * ((1.0f - fx) * c + fx * d);
}

/* Radiance arriving from map-space unit direction d. */
PRT_INLINE float3 envmap_radiance(__global const float* rgb, int width, int height, float3 d) {
    float2 xy = envmap_texel_coords(d, width, height);
    float x0 = floor(xy.x), y0 = floor(xy.y);
    return envmap_bilinear(rgb, width, height, (int)x0, (int)y0, xy.x - x0, xy.y - y0);
}

#endif
