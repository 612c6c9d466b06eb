"""Record the kernel launches of a run, to replay them under Oclgrind (replay.py).

``capturing(folder)`` wraps ``pipeline.device.cl.kernel`` so that every launch of a kernel it
hands out is recorded before it runs: the kernel file, name and defines, the include
folders, the global and local sizes, and every argument — a buffer's bytes as they are
at that moment (so an input is the data the kernel really read), a local-memory size,
or a scalar's bytes. At most ``per_kernel`` launches of each (file, kernel, defines) are
kept. One ``NNNN.json`` + ``NNNN.npz`` pair per launch.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


class _Recorder:
    def __init__(self, folder: Path, per_kernel: int) -> None:
        self.folder, self.per_kernel = folder, per_kernel
        self.counts: Counter = Counter()
        self.launches = 0
        folder.mkdir(parents=True, exist_ok=True)

    def record(self, file: str, name: str, defines: dict, queue: Any, global_size: Any,
               local_size: Any, args: tuple) -> None:
        import pyopencl as pcl

        from pipeline.searchpath import kernel_dirs

        key = (file, name, tuple(sorted((defines or {}).items())))
        if self.counts[key] >= self.per_kernel:
            return
        self.counts[key] += 1
        queue.finish()
        spec, arrays = [], {}
        for i, arg in enumerate(args):
            if isinstance(arg, pcl.LocalMemory):
                spec.append({"kind": "local", "nbytes": int(arg.size)})
            elif isinstance(arg, pcl.MemoryObjectHolder):
                host = np.empty(arg.size, np.uint8)
                pcl.enqueue_copy(queue, host, arg)
                arrays[f"a{i}"] = host
                spec.append({"kind": "buffer", "nbytes": int(arg.size)})
            elif arg is None:
                spec.append({"kind": "null"})
            else:
                value = np.asarray(arg)
                arrays[f"a{i}"] = np.frombuffer(value.tobytes(), np.uint8)
                spec.append({"kind": "scalar", "dtype": str(value.dtype)})
        stem = self.folder / f"{self.launches:04d}"
        self.launches += 1
        np.savez(stem.with_suffix(".npz"), **arrays)
        stem.with_suffix(".json").write_text(json.dumps({
            "file": file, "kernel": name, "defines": {k: str(v) for k, v in key[2]},
            "include": [str(d) for d in kernel_dirs()],
            "global": [int(n) for n in global_size],
            "local": None if local_size is None else [int(n) for n in local_size],
            "args": spec}))


class _RecordingKernel:
    """A kernel whose launches are recorded first; everything else is the kernel's."""

    def __init__(self, kernel: Any, recorder: _Recorder, file: str, name: str,
                 defines: dict | None) -> None:
        self._kernel, self._recorder = kernel, recorder
        self._where = (file, name, defines or {})

    def __call__(self, queue: Any, global_size: Any, local_size: Any, *args: Any,
                 **kwargs: Any) -> Any:
        self._recorder.record(*self._where, queue, global_size, local_size, args)
        return self._kernel(queue, global_size, local_size, *args, **kwargs)

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._kernel, attr)


@contextmanager
def capturing(folder: Path, per_kernel: int = 2) -> Iterator[_Recorder]:
    """Record the launches of every kernel handed out by ``pipeline.device.cl.kernel`` inside
    the block into ``folder``."""
    from pipeline.device import cl

    recorder, original = _Recorder(folder, per_kernel), cl.kernel

    def kernel(file: str, name: str, defines: dict | None = None) -> Any:
        return _RecordingKernel(original(file, name, defines), recorder, file, name, defines)

    cl.kernel = kernel
    try:
        yield recorder
    finally:
        cl.kernel = original
