/* Evaluate materials' BRDFs at arrays of direction pairs (local frame): the OpenCL side
 * of the NumPy/OpenCL agreement tests and of BRDF inspection tools.
 * One work-item per pair; out[i] = brdf_eval(material[i], wi[i], wo[i]) (RGB, 1/sr). */
#include "brdf.h"

__kernel void brdf_eval_pairs(__global const float* wi,          /* n * 3 */
                              __global const float* wo,          /* n * 3 */
                              __global const int* material,      /* n */
                              __global const float* materials,   /* nmat * MATERIAL_FLOATS */
                              const int n,
                              __global float* out)               /* n * 3 */
{
    int i = get_global_id(0);
    if (i >= n) return;
    float3 f = brdf_eval(materials + material[i] * MATERIAL_FLOATS, vload3(i, wi),
                         vload3(i, wo));
    vstore3(f, i, out);
}
