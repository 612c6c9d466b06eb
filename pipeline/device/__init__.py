"""What runs on the machine's compute devices: OpenCL (cl, devices: which device and
why), ray tracing (raytrace: Embree on the host; bvh: the project's BVH for the OpenCL
device), the threads a task may use (threads), the memory-bandwidth probe (bandwidth)
and the device twin of the spherical wavelet transform (sphwavelet_cl)."""
