"""Memory-bandwidth probe: the reference against which kernel efficiency is stated.

Two streaming copies of a buffer much larger than the caches (default 256 MiB), each
timed ``repeats`` times, median reported in GB/s (10⁹ bytes/s) counting bytes read plus
bytes written:

* ``opencl_copy_gbs``: kernels/bandwidth.cl on the OpenCL device the renderers use
  (timed by the device's profiling events);
* ``numpy_copy_gbs``: ``np.copyto`` on the host, single-threaded.

A memory-bound kernel's efficiency is its bytes moved per second divided by
``opencl_copy_gbs``.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from pipeline.device import cl


def probe(megabytes: int = 256, repeats: int = 7) -> dict[str, float | str]:
    """Median copy bandwidths (GB/s) and the OpenCL device's name."""
    import pyopencl as pcl

    n = megabytes * (1 << 20) // 16  # float4 elements
    host = np.ones(n * 4, np.float32)
    out = np.empty_like(host)
    numpy_s = []
    for _ in range(repeats):
        start = time.perf_counter()
        np.copyto(out, host)
        numpy_s.append(time.perf_counter() - start)

    ctx, queue = cl.context(), cl.queue()
    src = pcl.Buffer(ctx, pcl.mem_flags.READ_ONLY | pcl.mem_flags.COPY_HOST_PTR, hostbuf=host)
    dst = pcl.Buffer(ctx, pcl.mem_flags.WRITE_ONLY, host.nbytes)
    kernel = cl.kernel("bandwidth.cl", "stream_copy")
    cl.check_writes("stream_copy", dst, 16 * n)  # a float4 per work-item
    kernel(queue, (n,), None, src, dst).wait()  # warm-up: first touch of the pages
    device_ms = [cl.event_ms(kernel(queue, (n,), None, src, dst)) for _ in range(repeats)]
    moved = 2.0 * host.nbytes
    return {"opencl_copy_gbs": moved / (statistics.median(device_ms) * 1e-3) / 1e9,
            "numpy_copy_gbs": moved / statistics.median(numpy_s) / 1e9,
            "buffer_mib": megabytes, "repeats": repeats, "device": cl.device().name}
