/* Shadow rays and closest hits on the device, against the BVH of pipeline/device/bvh.py
 * (kernels/bvh.h). */
#include "bvh.h"

/* rays: n · (origin.xyz, tmax; direction.xyz, 0); out[i] = 1 where occluded. */
__kernel void occluded_rays(__global const float4* lo, __global const float4* hi,
                            __global const float4* tri, const int leaves,
                            __global const float4* rays, const int n, __global uchar* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float4 a = rays[2 * i], b = rays[2 * i + 1];
    out[i] = bvh_occluded(lo, hi, tri, leaves, a.xyz, b.xyz, a.w) ? 1 : 0;
}

/* Closest hits of n rays (as occluded_rays'): t[i] (tmax where none), the stored
 * triangle prim[i] (-1: none) and Embree's barycentrics u[i], v[i]. */
__kernel void closest_rays(__global const float4* lo, __global const float4* hi,
                           __global const float4* tri, const int leaves,
                           __global const float4* rays, const int n, __global float* t,
                           __global int* prim, __global float* u, __global float* v)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float4 a = rays[2 * i], b = rays[2 * i + 1];
    float h = a.w, s = 0.0f, r = 0.0f;
    prim[i] = bvh_closest(lo, hi, tri, leaves, a.xyz, b.xyz, a.w, &h, &s, &r);
    t[i] = h;
    u[i] = s;
    v[i] = r;
}

/* Visibility of every light sample from n points (build with light_defines() and
 * BVH_LEAF): vis[i · stride + offset + s] = 1 where sample s of a light is unoccluded,
 * as pipeline/render/shadows.py's light_visibility traces it with Embree — rays from
 * the point moved eps along its normal, only towards samples in front of the point
 * (n · (q − p) > 0, else 0: judged from p, not the moved origin, which an eps as large
 * as the near geometry, a scene of objects far apart, would put past the light), stopping just short of the sample (t < 1 − 1e-4 in units of q − o) or, for
 * a directional light, at `far`. Quad samples: sampling.h's stratified_square of
 * (pixel id, light, sample), as lights.h shades them. */
#include "lights.h"

__kernel void light_visibility(__global const float4* lo, __global const float4* hi,
                               __global const float4* tri, const int leaves,
                               __global const float* position, __global const float* normal,
                               __global const uint* pixel, __global const float* lights,
                               const int nlights, const int stride, const float eps,
                               const float far, const int n, __global uchar* vis)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 nn = vload3(i, normal);
    float3 p = vload3(i, position);
    float3 o = p + eps * nn;
    __global uchar* row = vis + (size_t)i * stride;
    for (int l = 0; l < nlights; ++l) {
        __global const float* light = lights + l * LIGHT_FLOATS;
        int kind = (int)light[LIGHT_TYPE], off = (int)light[LIGHT_SAMPLE_OFFSET];
        if (kind == LIGHT_DIRECTIONAL) {
            float3 d = -light_vec(light, LIGHT_DIRECTION);
            row[off] = dot(nn, d) > 0.0f && !bvh_occluded(lo, hi, tri, leaves, o, d, far);
            continue;
        }
        int count = kind == LIGHT_QUAD ? (int)light[LIGHT_SAMPLES] : 1;
        uint m = (uint)round(sqrt((float)count));
        float3 corner = light_vec(light, LIGHT_CORNER), eu = light_vec(light, LIGHT_EDGE_U),
               ev = light_vec(light, LIGHT_EDGE_V);
        for (int s = 0; s < count; ++s) {
            float3 q = corner;
            if (kind == LIGHT_QUAD) {
                float2 uv = stratified_square(pixel[i], (uint)l, (uint)s, m);
                q = corner + uv.x * eu + uv.y * ev;
            }
            float3 d = q - o;
            row[off + s] = dot(nn, q - p) > 0.0f
                && !bvh_occluded(lo, hi, tri, leaves, o, d, 1.0f - 1e-4f);
        }
    }
}
