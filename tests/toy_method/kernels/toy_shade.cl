#include "toy_common.h"

__kernel void toy_shade(__global const float *normal, __global float *shade, int n) {
    int i = get_global_id(0);
    if (i < n) shade[i] = fmax(normal[3 * i + TOY_UP], 0.0f);
}
