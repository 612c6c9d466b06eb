"""pipeline/device/cl.py: the OpenCL context's effect on the process, and the kernel cache."""

from __future__ import annotations

import pyopencl as pcl
import pytest
from threadpoolctl import threadpool_info

from pipeline.device import cl


def test_a_cpu_context_leaves_blas_one_thread():
    """On a CPU device, BLAS threads would spin beside the device's workers (measured:
    light-edit frames 1.5× slower): after the context exists, BLAS runs one thread."""
    if not cl.device().type & pcl.device_type.CPU:
        pytest.skip("a GPU context leaves BLAS alone")
    cl.context()
    import scipy.linalg  # noqa: F401  (SciPy's own OpenBLAS, loaded after the context)

    blas = [pool for pool in threadpool_info() if pool["user_api"] == "blas"]
    assert blas, "NumPy's BLAS is not visible to threadpoolctl"
    assert all(pool["num_threads"] == 1 for pool in blas)


def test_kernel_source_hash_follows_file_changes(tmp_path, monkeypatch):
    """Kernels are cached by a hash of the folders' sources, re-read only when a file's
    size or modification time changes; an edit changes the hash once the files are
    stat'ed again (after RESTAT_S; 0 here), and not before."""
    source = tmp_path / "k.cl"
    source.write_text("__kernel void k() {}\n")
    first = cl._source_hash([tmp_path])
    assert cl._source_hash([tmp_path]) == first
    source.write_text("__kernel void k() { int unused = 1; }\n")
    assert cl._source_hash([tmp_path]) == first  # within RESTAT_S: not looked at
    monkeypatch.setattr(cl, "RESTAT_S", 0.0)
    assert cl._source_hash([tmp_path]) != first


def test_a_launch_that_would_write_past_its_buffer_is_refused():
    """Issue 40 (host-side size checks): ``cl.run`` states what a kernel writes; a buffer
    smaller than that is refused before the launch, and nothing is written."""
    import numpy as np

    kernel = cl.kernel("d2i.cl", "add_scaled")  # total[i] += factor · bounce[i], float4
    bounce = cl.read_only_buffer(np.ones((8, 4), np.float32))
    small = pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, 16 * 4)
    with pytest.raises(RuntimeError, match="add_scaled would write 128 bytes into a "
                                           "buffer of 64"):
        cl.run(kernel, 8, bounce, np.ones(4, np.float32), np.int32(8), out=None,
               writes=16 * 8, out_buffer=small)
    with pytest.raises(TypeError, match="states its writes="):
        cl.run(kernel, 8, bounce, np.ones(4, np.float32), np.int32(8), out=None,
               out_buffer=small)


def test_a_direct_launch_that_would_write_past_its_buffer_is_refused():
    """The same check for kernels launched directly (the stages' wavelet, lighting and
    BRDF-table kernels)."""
    small = pcl.Buffer(cl.context(), pcl.mem_flags.READ_WRITE, 64)
    cl.check_writes("k", small, 64)  # exactly full: launched
    with pytest.raises(RuntimeError, match="kernel k would write 65 bytes into a buffer "
                                           "of 64"):
        cl.check_writes("k", small, 65)


@pytest.mark.parametrize("shape, dtype",
                         [((463, 3), "float32"), ((7,), "uint8"), ((0, 2), "int32")])
def test_aligned_arrays_start_on_a_page_and_carry_kernel_writes_back(shape, dtype):
    import numpy as np

    a = cl.aligned_empty(shape, dtype)
    assert a.shape == shape and a.dtype == np.dtype(dtype) and a.flags.c_contiguous
    if not a.size:  # an empty array holds no memory to align (buffers refuse it anyway)
        return
    assert a.ctypes.data % cl.PAGE == 0
    a[...] = 0
    buffer = cl.shared_output_buffer(a)
    pcl.enqueue_fill_buffer(cl.queue(), buffer, np.ones(1, dtype), 0, a.nbytes)
    cl.read_output_buffer(a, buffer)
    assert np.all(a == 1)
