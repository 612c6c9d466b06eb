/* Frame assembly on the device: a renderer's per-pixel results scattered into the image
 * buffer, so that a frame comes back to the host in one copy (pipeline/render/__init__.py
 * DeviceImage; NumPy twin: scatter_pixels). */

/* image[pixel[i]] = max(scale · values[i], 0), RGB float32 records; n values. Radiance
 * is never negative; a truncated basis (triple's wavelet rows under a map of very high
 * dynamic range, sg's lobes) can dip below 0 where the light is small against its
 * brightest texel, and that dip is clamped here, not shown. */
__kernel void scatter_rgb(__global const float* values, __global const int* pixel,
                          const float scale, const int n, __global float* image)
{
    int i = get_global_id(0);
    if (i >= n) return;
    vstore3(fmax(scale * vload3(i, values), (float3)(0.0f)), pixel[i], image);
}
