/* Environment map radiance at arrays of world directions: the OpenCL side of the
 * NumPy/OpenCL agreement test of kernels/envmap.h. One work-item per direction;
 * out[i] = radiance of the map rotated by the angle (cos c, sin s) about +y. */
#include "envmap.h"

__kernel void envmap_eval(__global const float* d,      /* n * 3, world, unit */
                          __global const float* rgb,    /* height * width * 3 */
                          const int width, const int height, const float c, const float s,
                          const int n,
                          __global float* out)          /* n * 3 */
{
    int i = get_global_id(0);
    if (i >= n) return;
    vstore3(envmap_radiance(rgb, width, height, envmap_from_world(vload3(i, d), c, s)),
            i, out);
}
