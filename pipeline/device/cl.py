"""OpenCL: the one place that owns devices, contexts, queues and program builds.

Kernels live in ``kernels/`` (and in folders that plug-ins add, pipeline/searchpath.py)
and are loaded by file name, built with ``-I`` for every kernel folder and sorted ``-D``
defines, and cached per (source hash of the folders' .cl/.h files, options, device).
The device is chosen by pipeline/device/devices.py (``PRT_CL_DEVICE``, else the first GPU,
else the first CPU implementation, each proved by a probe first).
"""

from __future__ import annotations

import hashlib
import time
import warnings
from functools import cache
from pathlib import Path
from typing import Any

from pipeline.device.threads import one_blas_thread
from pipeline.errors import PrtError
from pipeline.searchpath import find_kernel, kernel_dirs


def kernel_dir() -> Path:
    """The project's kernels folder, from a checkout or an installed wheel."""
    return kernel_dirs()[0]


@cache
def device() -> Any:
    """The OpenCL device of this process (pipeline/device/devices.py ``choose``)."""
    from pipeline.device.devices import choose

    return choose().device


@cache
def context() -> Any:
    """The OpenCL context of ``device()``. On a CPU device, this process's BLAS is limited
    to one thread first (pipeline/device/threads.py ``one_blas_thread``: its spinning threads
    would take the cores from the device's)."""
    import pyopencl as cl

    if device().type & cl.device_type.CPU:
        one_blas_thread()
    return cl.Context([device()])


@cache
def queue() -> Any:
    """An in-order queue with profiling, so kernel times come from events."""
    import pyopencl as cl

    return cl.CommandQueue(context(), properties=cl.command_queue_properties.PROFILING_ENABLE)


_SIGNATURES: dict[tuple[Path, ...], tuple[float, str]] = {}
RESTAT_S = 1.0  # a folder's files are stat'ed again after this many seconds


def _source_hash(folders: list[Path]) -> str:
    """Hash of the folders' kernel sources and headers; re-read only when a file's name,
    size or modification time changes, and those stat'ed at most once per ``RESTAT_S``
    (a frame looks up several kernels: a few hundred stat calls each time were ≈ 2 ms
    of a GPU frame)."""
    key, now = tuple(folders), time.monotonic()
    if key in _SIGNATURES and now - _SIGNATURES[key][0] < RESTAT_S:
        return _SIGNATURES[key][1]
    paths = sorted(p for folder in folders for p in folder.glob("*.[ch]*"))
    signature = tuple((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in paths)
    _SIGNATURES[key] = (now, _hash_sources(tuple(paths), signature))
    return _SIGNATURES[key][1]


@cache
def _hash_sources(paths: tuple[Path, ...], signature: tuple) -> str:
    """SHA-256 of the files' names and bytes; ``signature`` only keys the cache."""
    h = hashlib.sha256()
    for path in paths:
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


_PROGRAMS: dict[tuple[str, str, tuple[str, ...], str], Any] = {}


_RECENT: dict[tuple, tuple[float, Any]] = {}  # (name, defines) -> (time, program)


def program(name: str, defines: dict[str, Any] | None = None) -> Any:
    """The built program of kernel file ``name`` (found in the kernel folders,
    pipeline/searchpath.py) with ``-D`` defines, cached; looked up again (the file found,
    the sources' hash checked) at most once per ``RESTAT_S`` (a frame asks for its
    kernels dozens of times)."""
    import pyopencl as cl

    recent_key, now = (name, tuple(sorted((defines or {}).items()))), time.monotonic()
    recent = _RECENT.get(recent_key)
    if recent is not None and now - recent[0] < RESTAT_S:
        return recent[1]
    folders = kernel_dirs()
    path = find_kernel(name)
    if path is None:
        raise PrtError(folders[0] / name, "kernel source not found")
    includes = [arg for folder in folders for arg in ("-I", str(folder))]
    dev = device()
    options = (*includes, *(f"-D{k}={v}" for k, v in sorted(
        {**device_defines(dev), **(defines or {})}.items())))
    key = (name, _source_hash(folders), options,
           f"{dev.platform.name}|{dev.name}|{dev.driver_version}")
    if key not in _PROGRAMS:
        try:
            with warnings.catch_warnings():  # a compiler's log of a build that succeeded
                warnings.simplefilter("ignore", cl.CompilerWarning)
                _PROGRAMS[key] = cl.Program(context(), path.read_text()).build(
                    options=list(options))
        except cl.RuntimeError as exc:
            raise PrtError(path, f"OpenCL build failed: {exc}") from None
    _RECENT[recent_key] = (now, _PROGRAMS[key])
    return _PROGRAMS[key]


def device_defines(dev: Any) -> dict[str, int]:
    """Defines that tell a kernel which implementation builds it: ``PRT_POCL`` on PoCL
    (kernels/triple/triple_surface.cl uses a clang builtin there that is not OpenCL C)."""
    from pipeline.device.devices import implementation

    return {"PRT_POCL": 1} if implementation(dev) == "pocl" else {}


_KERNELS: dict[tuple, Any] = {}


def kernel(file: str, name: str, defines: dict[str, Any] | None = None) -> Any:
    """The kernel ``name`` of ``kernels/<file>``, retrieved once per built program."""
    import pyopencl as cl

    prog = program(file, defines)
    key = (id(prog), name)
    if key not in _KERNELS:
        _KERNELS[key] = cl.Kernel(prog, name)
    return _KERNELS[key]


def run(kernel: Any, size: int, *args: Any, out: Any, writes: int | None = None,
        out_buffer: Any | None = None, local: int | None = None) -> float:
    """One launch of ``kernel`` over ``size`` work-items with ``args`` and, last, the
    output buffer (``out_buffer``, or a new write-only one of ``out``'s size); the output
    is copied into the host array ``out`` (``out=None``: it stays in ``out_buffer``, for
    a later kernel). Returns the kernel's milliseconds. With ``local``, work-groups of
    that size (the global size rounded up: the kernel skips the extra items): PoCL
    builds a kernel once per work-group size, so a size that changes from frame to frame
    (pixels seen) would otherwise re-build it (seconds).

    ``writes``: the bytes the kernel writes into the output buffer, as its caller
    computes them from the kernel's contract (records × record size; default, ``out``
    whole); the launch is refused when the buffer (or ``out``) is smaller, so that no
    kernel writes past what the host allocated (the device side: every kernel replayed
    under Oclgrind, tests/test_oclgrind.py)."""
    import pyopencl as cl

    if writes is None:
        if out is None:
            raise TypeError("cl.run: a launch into out_buffer alone states its writes=")
        writes = out.nbytes

    if out_buffer is None:
        out_buffer = cl.Buffer(context(), cl.mem_flags.WRITE_ONLY, max(out.nbytes, 1))
    held = out_buffer.size if out is None else min(out_buffer.size, out.nbytes)
    if writes > held:
        raise RuntimeError(f"kernel {kernel.function_name} would write {writes} bytes into "
                           f"a buffer of {held}: refusing to launch it")
    event = enqueue(kernel, size, *args, out_buffer, local=local)
    if out is not None:
        cl.enqueue_copy(queue(), out, out_buffer, wait_for=[event])
    return event_ms(event)


def check_writes(kernel: str, buffer: Any, writes: int) -> None:
    """Refuse a launch of ``kernel`` that would write ``writes`` bytes (its contract:
    records × record size) into a device ``buffer`` smaller than that: the host-side
    size check that :func:`run` makes, for kernels launched directly."""
    if writes > buffer.size:
        raise RuntimeError(f"kernel {kernel} would write {writes} bytes into a buffer of "
                           f"{buffer.size}: refusing to launch it")


def enqueue(kernel: Any, size: int, *args: Any, local: int | None = None) -> Any:
    """One launch of ``kernel`` over ``size`` work-items (rounded up to ``local``, as
    :func:`run`), not waited for: its event. Launches that follow one another on the
    in-order queue need no host round trip between them; :func:`event_ms` of each, once
    the last is done, gives their times."""
    shape = (size,) if local is None else (-(-size // local) * local,)
    return kernel(queue(), shape, None if local is None else (local,), *args)


def scratch_buffer(cache: dict[str, Any], name: str, nbytes: int) -> Any:
    """A read-write device buffer of at least ``nbytes`` (≥ 1), kept in ``cache`` under
    ``name`` and grown when a larger one is asked for (per-frame intermediates)."""
    import pyopencl as cl

    nbytes = max(int(nbytes), 1)
    if name not in cache or cache[name].size < nbytes:
        cache[name] = cl.Buffer(context(), cl.mem_flags.READ_WRITE, nbytes)
    return cache[name]


def event_ms(event: Any) -> float:
    """Milliseconds between an event's start and end (profiling clock); waits for it."""
    event.wait()
    return (event.profile.end - event.profile.start) * 1e-6


def read_only_buffer(array: Any) -> Any:
    """A read-only device copy of a NumPy array (one zero element if it is empty:
    OpenCL has no empty buffers)."""
    import numpy as np
    import pyopencl as cl

    a = np.ascontiguousarray(array)
    return cl.Buffer(context(), cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                     hostbuf=a if a.size else np.zeros(1, a.dtype))


def shared_read_only_buffer(array: Any) -> Any:
    """A read-only buffer of a large NumPy array that stays unchanged for the buffer's
    life: on a CPU device the array's own memory (USE_HOST_PTR: PoCL reads it in place,
    so a 1 GB table is resident once, not twice; the buffer holds a reference to it), on
    a GPU a device copy as :func:`read_only_buffer`."""
    import numpy as np
    import pyopencl as cl

    a = np.ascontiguousarray(array)
    if not a.size or not device().type & cl.device_type.CPU:
        return read_only_buffer(a)
    return cl.Buffer(context(), cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR, hostbuf=a)


PAGE = 4096  # bytes: a multiple of every device's base-address alignment (Intel's: 128)


def aligned_empty(shape: Any, dtype: Any) -> Any:
    """An uninitialised NumPy array whose data starts on a :data:`PAGE` boundary: a CPU
    runtime uses such memory in place for the USE_HOST_PTR buffers of
    :func:`shared_read_only_buffer` and :func:`shared_output_buffer` (Intel's copies an
    array that is not aligned to the device's base-address alignment; NumPy's own
    allocations are aligned to 16 bytes)."""
    import numpy as np

    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    raw = np.empty(nbytes + PAGE, np.uint8)
    start = -raw.ctypes.data % PAGE
    return raw[start:start + nbytes].view(dtype).reshape(shape)


def shared_output_buffer(array: Any) -> Any:
    """A buffer for kernels' output into the NumPy array ``array``, starting from its
    values (entries no kernel writes keep them): on a CPU device the array's own memory
    (USE_HOST_PTR: no copy either way), elsewhere a device copy; :func:`read_output_buffer`
    brings the result back."""
    import pyopencl as cl

    flags = cl.mem_flags.READ_WRITE
    if device().type & cl.device_type.CPU:
        return cl.Buffer(context(), flags | cl.mem_flags.USE_HOST_PTR, hostbuf=array)
    return cl.Buffer(context(), flags | cl.mem_flags.COPY_HOST_PTR, hostbuf=array)


def read_output_buffer(array: Any, buffer: Any) -> None:
    """``array`` (the host array of :func:`shared_output_buffer`) made current with the
    kernels' writes to ``buffer`` (after the queue's launches): a map and unmap where it
    is the buffer's memory, a copy otherwise."""
    import pyopencl as cl

    if buffer.flags & cl.mem_flags.USE_HOST_PTR:
        mapped, _ = cl.enqueue_map_buffer(queue(), buffer, cl.map_flags.READ, 0,
                                          array.shape, array.dtype)
        mapped.base.release(queue())
        queue().finish()
    else:
        cl.enqueue_copy(queue(), array, buffer)
