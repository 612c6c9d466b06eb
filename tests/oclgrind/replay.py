"""Replay recorded kernel launches (capture.py) on one OpenCL device and report what the
device says about each: ``python replay.py PLATFORM FOLDER [NNNN ...]``.

Imports only NumPy and pyopencl (a whole ``prt`` process under Oclgrind crashed: two
LLVMs in one process). For each launch: the program built from its file with its
``-I``/``-D`` options, its buffers made from the recorded bytes, the kernel run, the
queue finished. Between launches a line ``@@ launch NNNN FILE:KERNEL`` goes to stderr, so
that the device's own messages (Oclgrind writes its diagnostics there) can be told apart
by launch; ``@@ done`` ends the run.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pyopencl as cl


def main(platform: str, folder: Path, only: list[str]) -> None:
    import os

    extra = os.environ.get("REPLAY_BUILD_OPTIONS", "").split()
    device = next(d for p in cl.get_platforms() if platform.lower() in p.name.lower()
                  for d in p.get_devices())
    context = cl.Context([device])
    queue = cl.CommandQueue(context)
    programs: dict[tuple, cl.Program] = {}
    for meta_path in sorted(folder.glob("*.json")):
        if only and meta_path.stem not in only:
            continue
        meta = json.loads(meta_path.read_text())
        arrays = np.load(meta_path.with_suffix(".npz"))
        options = [a for d in meta["include"] for a in ("-I", d)]
        options += [f"-D{k}={v}" for k, v in sorted(meta["defines"].items())] + extra
        source = next(Path(d) / meta["file"] for d in meta["include"]
                      if (Path(d) / meta["file"]).is_file())
        key = (str(source), tuple(options))
        if key not in programs:
            programs[key] = cl.Program(context, source.read_text()).build(options=options)
        kernel = cl.Kernel(programs[key], meta["kernel"])
        args = []
        for i, spec in enumerate(meta["args"]):
            if spec["kind"] == "buffer":
                data = arrays[f"a{i}"]
                args.append(cl.Buffer(context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                                      hostbuf=data) if data.size else
                            cl.Buffer(context, cl.mem_flags.READ_WRITE, 1))
            elif spec["kind"] == "local":
                args.append(cl.LocalMemory(spec["nbytes"]))
            elif spec["kind"] == "scalar":
                value = np.frombuffer(arrays[f"a{i}"].tobytes(), spec["dtype"])
                args.append(value[0] if value.size == 1 else value)  # a vector: its array
            else:
                args.append(None)
        print(f"@@ launch {meta_path.stem} {meta['file']}:{meta['kernel']} "
              f"global {meta['global']} local {meta['local']}", file=sys.stderr, flush=True)
        kernel(queue, tuple(meta["global"]), None if meta["local"] is None
               else tuple(meta["local"]), *args)
        queue.finish()
        sys.stderr.flush()
    print("@@ done", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main(sys.argv[1], Path(sys.argv[2]), sys.argv[3:])
