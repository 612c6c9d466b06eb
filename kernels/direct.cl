/* Direct lighting of a G-buffer by point, spot, directional and quad lights with each
 * material's analytic BRDF (brdf.h); shadows come in as a visibility mask traced by
 * Embree. One work-item per pixel. Output: linear RGB radiance, float3 per pixel.
 * Built with pipeline.math.lights.light_defines() (the light row layout, lights.h). */
#include "brdf.h"
#include "lights.h"

/* The direct light leaving row k of the G-buffer arrays, pixel `pixel` of the image (its
 * light samples' stratification, lights.h), towards the camera. */
PRT_INLINE float3 direct_pixel(int k, uint pixel, __global const float* position,
                               __global const float* normal, __global const float* tangent,
                               __global const int* object_id, __global const int* material_id,
                               __global const float* materials, __global const float* lights,
                               const int nlights, __global const uchar* visibility,
                               const int nsamples, const float3 camera)
{
    int m = material_id[k];
    float3 rgb = (float3)(0.0f);
    if (m >= 0) {
        float3 p = vload3(k, position);
        float3 n = vload3(k, normal);
        float3 t = vload3(k, tangent);
        float3 view = normalize(p - camera);
        float3 wo = to_local(-view, n, t);
        __global const float* mat = materials + m * MATERIAL_FLOATS;
        __global const uchar* vis = visibility + (size_t)k * nsamples;
        for (int l = 0; l < nlights; ++l) {
            __global const float* row = lights + l * LIGHT_FLOATS;
            rgb += light_vec(row, LIGHT_RGB) * light_reflected(row, (uint)l, pixel, p, n, t, wo,
                                                        mat, vis);
        }
        rgb += quad_emission(lights, nlights, object_id[k], view);
    }
    return rgb;
}

__kernel void direct_lighting(__global const float* position,    /* npix * 3 */
                              __global const float* normal,      /* npix * 3 */
                              __global const float* tangent,     /* npix * 3 */
                              __global const int* object_id,     /* npix */
                              __global const int* material_id,   /* npix */
                              __global const float* materials,   /* nmat * MATERIAL_FLOATS */
                              __global const float* lights,      /* nlights * LIGHT_FLOATS */
                              const int nlights,
                              __global const uchar* visibility,  /* npix * nsamples */
                              const int nsamples,
                              const float3 camera,
                              const int npix,
                              __global float* out)               /* npix * 3 */
{
    int i = get_global_id(0);
    if (i >= npix) return;
    vstore3(direct_pixel(i, (uint)i, position, normal, tangent, object_id, material_id,
                         materials, lights, nlights, visibility, nsamples, camera), i, out);
}

/* direct_lighting of some pixels only, `pixel` (their ids in the image), from G-buffer
 * arrays and visibility rows compacted to them (row i: pixel[i]); the same function per
 * pixel, so each pixel's value is direct_lighting's, bit for bit (d2i's BRDF-edit mode
 * re-shades only the pixels whose material changed). */
__kernel void direct_lighting_pixels(__global const float* position,
                                     __global const float* normal,
                                     __global const float* tangent,
                                     __global const int* object_id,
                                     __global const int* material_id,
                                     __global const float* materials,
                                     __global const float* lights,
                                     const int nlights,
                                     __global const uchar* visibility,
                                     const int nsamples,
                                     const float3 camera,
                                     __global const uint* pixel,
                                     const int n,
                                     __global float* out)          /* n * 3 */
{
    int i = get_global_id(0);
    if (i >= n) return;
    vstore3(direct_pixel(i, pixel[i], position, normal, tangent, object_id, material_id,
                         materials, lights, nlights, visibility, nsamples, camera), i, out);
}

/* The gather samples' directly lit radiance L_d = kd/π ⊙ E (method d2i: Lambertian at
 * the gathers, pipeline/methods/d2i/render.py; NumPy twin kd/π ⊙ pipeline/math/lights.py
 * shade_direct with a unit BRDF). `materials` holds Lambertian rows of each material's
 * albedo, so that lights.h's light_reflected (its BRDF kd/π, the viewer along the
 * normal) gives kd/π times the geometry and visibility sum; `pixel` the gathers' light
 * sample ids. One work-item per gather; out float4 (RGB, 0). */
__kernel void gather_direct(__global const float* position, __global const float* normal,
                            __global const uint* pixel, __global const int* material,
                            __global const float* materials, __global const float* lights,
                            const int nlights, __global const uchar* visibility,
                            const int nsamples, const int n, __global float4* out)
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 p = vload3(i, position), nn = vload3(i, normal);
    float3 t = normalize(cross(nn, fabs(nn.x) > 0.9f ? (float3)(0.0f, 1.0f, 0.0f)
                                                    : (float3)(1.0f, 0.0f, 0.0f)));
    __global const float* mat = materials + material[i] * MATERIAL_FLOATS;
    __global const uchar* vis = visibility + (size_t)i * nsamples;
    float3 rgb = (float3)(0.0f);
    for (int l = 0; l < nlights; ++l) {
        __global const float* row = lights + l * LIGHT_FLOATS;
        rgb += light_vec(row, LIGHT_RGB) * light_reflected(row, (uint)l, pixel[i], p, nn, t,
                                                       (float3)(0.0f, 0.0f, 1.0f), mat, vis);
    }
    out[i] = (float4)(rgb, 0.0f);
}
