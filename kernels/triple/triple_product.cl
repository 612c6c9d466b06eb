/* Triple products ∫ f g h dω of interpolated sparse wavelet functions, one per work-item:
 * the OpenCL side of the NumPy agreement tests and of inspection tools; the renderer
 * calls sw_triple the same way (sphwavelet.h).
 * Item i: function f ∈ {0, 1, 2} is Σ_r weight[f][i][r] · row rows[f][i][r] of table f
 * for r < count[f][i] (≤ SW_ROWS); table f has channels[f] values per entry (1 or 3);
 * weights are RGB. out[i] is the RGB triple product. */
#include "sphwavelet.h"

__kernel void triple_products(__global const uint* start0, __global const ushort* index0,
                              __global const float* value0,
                              __global const uint* start1, __global const ushort* index1,
                              __global const float* value1,
                              __global const uint* start2, __global const ushort* index2,
                              __global const float* value2,
                              const int3 channels,
                              __global const uint* rows,     /* n * 3 * SW_ROWS */
                              __global const float* weight,  /* n * 3 * SW_ROWS * 3 */
                              __global const int* count,     /* n * 3 */
                              __global const float* root_area,
                              __global const float* wavelet,
                              __global const float* tensor,
                              const int n,
                              __global float* out)           /* n * 3 */
{
    int i = get_global_id(0);
    if (i >= n) return;
    uint r[SW_ROWS];
    float3 w[SW_ROWS];
    int ch[3] = {channels.x, channels.y, channels.z};
    sw_source src[3];
    __global const uint* starts[3] = {start0, start1, start2};
    __global const ushort* indices[3] = {index0, index1, index2};
    __global const float* values[3] = {value0, value1, value2};
    for (int f = 0; f < 3; ++f) {
        int k = count[3 * i + f];
        for (int j = 0; j < k; ++j) {
            r[j] = rows[(3 * i + f) * SW_ROWS + j];
            w[j] = vload3((3 * i + f) * SW_ROWS + j, weight);
        }
        sw_open(&src[f], starts[f], indices[f], values[f], ch[f], r, w, k);
    }
    vstore3(sw_triple(src, root_area, wavelet, tensor), i, out);
}
