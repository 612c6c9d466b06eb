/* Direct lighting of a G-buffer by point, spot, directional and quad lights with each
 * material's analytic BRDF (brdf.h); shadows come in as a visibility mask traced by
 * Embree. One work-item per pixel. Output: linear RGB radiance, float3 per pixel.
 * Built with pipeline.math.lights.light_defines() (the light row layout, lights.h). */
#include "brdf.h"
#include "lights.h"

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
    int m = material_id[i];
    float3 rgb = (float3)(0.0f);
    if (m >= 0) {
        float3 p = vload3(i, position);
        float3 n = vload3(i, normal);
        float3 t = vload3(i, tangent);
        float3 view = normalize(p - camera);
        float3 wo = to_local(-view, n, t);
        __global const float* mat = materials + m * MATERIAL_FLOATS;
        __global const uchar* vis = visibility + (size_t)i * nsamples;
        for (int l = 0; l < nlights; ++l) {
            __global const float* row = lights + l * LIGHT_FLOATS;
            rgb += light_vec(row, LIGHT_RGB) * light_reflected(row, (uint)l, (uint)i, p, n, t, wo,
                                                        mat, vis);
        }
        rgb += quad_emission(lights, nlights, object_id[i], view);
    }
    vstore3(rgb, i, out);
}
