/* Frame assembly on the device: a renderer's per-pixel results scattered into the image
 * buffer, so that a frame comes back to the host in one copy (pipeline/render/__init__.py
 * DeviceImage; NumPy twin: scatter_pixels). */

/* image[pixel[i]] = scale · values[i], RGB float32 records; n values. */
__kernel void scatter_rgb(__global const float* values, __global const int* pixel,
                          const float scale, const int n, __global float* image)
{
    int i = get_global_id(0);
    if (i >= n) return;
    vstore3(scale * vload3(i, values), pixel[i], image);
}
