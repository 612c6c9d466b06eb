"""Each method's tiny frames on this process's OpenCL device:
``python device_frames.py WORK OUT.npz`` (``PRT_CL_DEVICE`` picks the device).

Bakes what is stale under WORK (tests/tiny_scenes.py, 24² images), renders direct, d2i
(both product layouts), triple and sg, and saves the frames with the implementation's
name (``impl``). tests/test_device_frames.py runs it once per implementation over one
bake, so that only the frames' kernels differ."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent
sys.path[:0] = [str(TESTS), str(TESTS.parent)]
os.environ.setdefault("PRT_JOBS", "1")

from tiny_scenes import tiny_scene  # noqa: E402

SIZE = 24
FRAMES = {"direct": ("d2i", {}), "d2i": ("d2i", {"layout": "cpu"}),
          "d2i_gpu_layout": ("d2i", {"layout": "gpu"}), "triple": ("triple", {}),
          "sg": ("sg", {})}


def main(work: Path, out: Path) -> None:
    from pipeline import job
    from pipeline.device import cl
    from pipeline.device.devices import implementation

    frames = {}
    for name, (scene_of, options) in FRAMES.items():
        sc = tiny_scene(work, scene_of, SIZE)
        wd = job.workdir_for(sc, work / scene_of / "w")
        job.bake(sc, wd, quiet=True)
        method = name if name in ("direct", "triple", "sg") else "d2i"
        frames[name] = job.render_frame(sc, wd, method, options).rgb
    np.savez(out, impl=implementation(cl.device()), **frames)


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
