/* Direct lighting from packed lights; the same formulas as pipeline/math/lights.py
 * (see its docstring for the row layout, units and equations).
 *
 * The row layout is defined once, by pipeline.math.lights.LightRow: a kernel including
 * this header is built with its defines (pipeline.math.lights.light_defines()):
 * LIGHT_FLOATS, the field offsets LIGHT_TYPE, LIGHT_POSITION (= LIGHT_CORNER),
 * LIGHT_DIRECTION (= LIGHT_EDGE_U), LIGHT_EDGE_V, LIGHT_RGB, LIGHT_COS_OUTER,
 * LIGHT_COS_INNER, LIGHT_SAMPLES, LIGHT_OBJECT, LIGHT_SAMPLE_OFFSET, and the type codes
 * LIGHT_POINT, LIGHT_SPOT, LIGHT_DIRECTIONAL, LIGHT_QUAD. */
#ifndef PRT_LIGHTS_H
#define PRT_LIGHTS_H

#include "inline.h"

#include "brdf.h"
#include "sampling.h"

#ifndef LIGHT_FLOATS
#error "lights.h: build with pipeline.math.lights.light_defines() (the light row layout)"
#endif

PRT_INLINE float3 light_vec(__global const float* row, int at) {
    return (float3)(row[at], row[at + 1], row[at + 2]);
}

inline float smoothstep_f(float e0, float e1, float x) {
    float t = clamp((x - e0) / (e1 - e0), 0.0f, 1.0f);
    return t * t * (3.0f - 2.0f * t);
}

/* Radiance reflected at p towards the viewer by light `row`, without the light's RGB:
 * the sum over its samples of f(wi, wo) * geometry term (see pipeline/math/lights.py).
 * n, t: unit normal and tangent; wo: unit direction to the viewer in the local frame;
 * mat: the material row (brdf.h); vis: the pixel's visibility row. */
PRT_INLINE float3 light_reflected(__global const float* row, uint index, uint pixel, float3 p,
                              float3 n, float3 t, float3 wo, __global const float* mat,
                              __global const uchar* vis) {
    int kind = (int)row[LIGHT_TYPE];
    int off = (int)row[LIGHT_SAMPLE_OFFSET];
    if (kind == LIGHT_DIRECTIONAL) {
        float3 l = -light_vec(row, LIGHT_DIRECTION);
        float c = dot(n, l);
        return vis[off] && c > 0.0f ? brdf_eval(mat, to_local(l, n, t), wo) * c
                                    : (float3)(0.0f);
    }
    if (kind == LIGHT_QUAD) {
        int count = (int)row[LIGHT_SAMPLES];
        uint m = (uint)round(sqrt((float)count));
        float3 corner = light_vec(row, LIGHT_CORNER), eu = light_vec(row, LIGHT_EDGE_U),
               ev = light_vec(row, LIGHT_EDGE_V);
        float3 nq = cross(eu, ev);
        float area = length(nq);
        nq = nq / area;
        float3 sum = (float3)(0.0f);
        for (int s = 0; s < count; ++s) {
            if (!vis[off + s]) continue;
            float2 uv = stratified_square(pixel, index, (uint)s, m);
            float3 d = corner + uv.x * eu + uv.y * ev - p;
            float r2 = dot(d, d);
            float3 l = d / sqrt(r2);
            float g = fmax(0.0f, dot(n, l)) * fmax(0.0f, -dot(nq, l)) / r2;
            if (g > 0.0f) sum += brdf_eval(mat, to_local(l, n, t), wo) * g;
        }
        return sum * (area / (float)count);
    }
    if (!vis[off]) return (float3)(0.0f);
    float3 d = light_vec(row, LIGHT_POSITION) - p;
    float r2 = dot(d, d);
    float3 l = d / sqrt(r2);
    float g = fmax(0.0f, dot(n, l)) / r2;
    if (kind == LIGHT_SPOT)
        g *= smoothstep_f(row[LIGHT_COS_OUTER], row[LIGHT_COS_INNER],
                          -dot(l, light_vec(row, LIGHT_DIRECTION)));
    return g > 0.0f ? brdf_eval(mat, to_local(l, n, t), wo) * g : (float3)(0.0f);
}

/* Radiance seen directly on the front of quad lights' emitting objects. */
PRT_INLINE float3 quad_emission(__global const float* lights, int nlights, int object, float3 view) {
    float3 e = (float3)(0.0f);
    for (int i = 0; i < nlights; ++i) {
        __global const float* row = lights + i * LIGHT_FLOATS;
        if ((int)row[LIGHT_TYPE] == LIGHT_QUAD && (int)row[LIGHT_OBJECT] == object &&
            object >= 0 &&
            dot(view, cross(light_vec(row, LIGHT_EDGE_U), light_vec(row, LIGHT_EDGE_V))) < 0.0f)
            e += light_vec(row, LIGHT_RGB);
    }
    return e;
}

#endif
