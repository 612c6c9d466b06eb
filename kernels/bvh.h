/* Occlusion and closest hits against the implicit BVH of pipeline/device/bvh.py (see its docstring): node k's
 * box is lo[k], hi[k] (float4, w unused), its children 2k and 2k + 1, the `leaves`
 * leaves are nodes leaves … 2·leaves − 1, leaf j holds triangles j·BVH_LEAF … + BVH_LEAF
 * − 1, each three float4 (v0, e1, e2). Build with -D BVH_LEAF. */
#ifndef PRT_BVH_H
#define PRT_BVH_H

#include "inline.h"

#define BVH_STACK 64

/* Whether the ray o + t d enters the box for some t in [0, tmax]; inv = 1 / d. Each
 * axis takes the entry plane by the sign of inv, so an inverted (empty) box is never
 * entered; 0 · inf = NaN (a ray in a box face's plane) is dropped by fmin/fmax. */
PRT_INLINE bool bvh_box(float4 lo, float4 hi, float3 o, float3 inv, float tmax) {
    float3 t_lo = (lo.xyz - o) * inv, t_hi = (hi.xyz - o) * inv;
    int3 forward = isgreaterequal(inv, (float3)(0.0f));
    float3 t_in = select(t_hi, t_lo, forward), t_out = select(t_lo, t_hi, forward);
    float enter = fmax(fmax(t_in.x, t_in.y), fmax(t_in.z, 0.0f));
    float leave = fmin(fmin(t_out.x, t_out.y), fmin(t_out.z, tmax));
    return enter <= leave;
}

/* Möller–Trumbore, both sides, for the closest hit: whether the ray hits the triangle
 * at 0 < t < tmax, with *t and Embree's barycentrics (*u, *v): the hit point is
 * (1 − u − v) v0 + u v1 + v v2. */
PRT_INLINE bool bvh_triangle_hit(__global const float4* tri, float3 o, float3 d, float tmax,
                                 float* t, float* u, float* v) {
    float3 v0 = tri[0].xyz, e1 = tri[1].xyz, e2 = tri[2].xyz;
    float3 p = cross(d, e2);
    float det = dot(e1, p);
    if (det == 0.0f) return false;  /* parallel, or a padding triangle */
    float inv = 1.0f / det;
    float3 s = o - v0;
    float a = dot(s, p) * inv;
    if (a < 0.0f || a > 1.0f) return false;
    float3 q = cross(s, e1);
    float b = dot(d, q) * inv;
    if (b < 0.0f || a + b > 1.0f) return false;
    float h = dot(e2, q) * inv;
    if (!(h > 0.0f && h < tmax)) return false;
    *t = h;
    *u = a;
    *v = b;
    return true;
}

/* Möller–Trumbore, both sides: a hit at 0 < t < tmax (t in units of |d|). */
PRT_INLINE bool bvh_triangle(__global const float4* tri, float3 o, float3 d, float tmax) {
    float t, u, v;
    return bvh_triangle_hit(tri, o, d, tmax, &t, &u, &v);
}

/* The closest hit on o + t d, 0 < t < tmax: depth first, boxes tested against the
 * nearest hit so far. Returns the stored triangle's index (-1: none) with *t, *u, *v
 * (bvh_triangle_hit's; ties between triangles at equal t go to the first visited). */
PRT_INLINE int bvh_closest(__global const float4* lo, __global const float4* hi,
                           __global const float4* tri, int leaves, float3 o, float3 d,
                           float tmax, float* t, float* u, float* v) {
    float3 inv = 1.0f / d;
    int stack[BVH_STACK];
    int top = 0, node = 1, found = -1;
    float best = tmax;
    for (;;) {
        if (bvh_box(lo[node], hi[node], o, inv, best)) {
            if (node < leaves) {
                stack[top++] = 2 * node + 1;
                node = 2 * node;
                continue;
            }
            int first = (node - leaves) * BVH_LEAF;
            for (int k = 0; k < BVH_LEAF; ++k) {
                float h, a, b;
                if (bvh_triangle_hit(tri + 3 * (first + k), o, d, best, &h, &a, &b)) {
                    best = h;
                    *u = a;
                    *v = b;
                    found = first + k;
                }
            }
        }
        if (top == 0) break;
        node = stack[--top];
    }
    *t = best;
    return found;
}

/* Whether anything lies on o + t d, 0 < t < tmax: depth first, any hit ends it. */
PRT_INLINE bool bvh_occluded(__global const float4* lo, __global const float4* hi,
                         __global const float4* tri, int leaves, float3 o, float3 d,
                         float tmax) {
    float3 inv = 1.0f / d;
    int stack[BVH_STACK];
    int top = 0, node = 1;
    for (;;) {
        if (bvh_box(lo[node], hi[node], o, inv, tmax)) {
            if (node < leaves) {
                stack[top++] = 2 * node + 1;
                node = 2 * node;
                continue;
            }
            __global const float4* t = tri + 3 * (node - leaves) * BVH_LEAF;
            for (int k = 0; k < BVH_LEAF; ++k)
                if (bvh_triangle(t + 3 * k, o, d, tmax)) return true;
        }
        if (top == 0) return false;
        node = stack[--top];
    }
}

#endif
