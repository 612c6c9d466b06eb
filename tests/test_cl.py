"""pipeline/cl.py: the OpenCL context's effect on the process, and the kernel cache."""

from __future__ import annotations

import pyopencl as pcl
import pytest
from threadpoolctl import threadpool_info

from pipeline import cl


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
