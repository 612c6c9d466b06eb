"""Each method's tiny scene (tests/helpers.py's floor, box and ball) with settings cut so
that a bake takes seconds: for tests that run every method on every device
(tests/oclgrind/scenarios.py, tests/device_frames.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from helpers import small_scene_dict, write_scene

SETTINGS = {
    "d2i": {"gather.count": 64, "bounce.block": 32, "transfer.tile": 8},
    "triple": {"triple.leaf_level": 2, "triple.visibility_refine": 1,
               "triple.frame_grid": [8, 5, 8], "triple.view_grid": [8, 4],
               "triple.texture_max": 16, "triple.texel_tile": 16, "triple.light_block": 64,
               "triple.store_budget": 64, "triple.light_budget": 64},
    "sg": {"sg.fit_grid": [9, 18], "sg.indirect_samples": 4, "sg.diffuse_samples": 16,
           "sg.diffuse_order": 3, "sg.fit_batch": 32},
}
ENVIRONMENT_LIT = ("triple", "sg")


def sky_map(path: Path) -> Path:
    """A 16 × 32 latitude-longitude map: sky, ground and a bright warm blob."""
    from pipeline.images import write_exr

    rows = (np.arange(16) + 0.5) / 16
    rgb = np.where(rows[:, None, None] < 0.5, [0.3, 0.4, 0.6], [0.05, 0.04, 0.03])
    rgb = np.broadcast_to(rgb, (16, 32, 3)).astype(np.float32).copy()
    rgb[4:6, 10:13] = [6.0, 4.0, 2.0]
    write_exr(path, rgb)
    return path


def tiny_scene(work: Path, method: str, size: int = 8):
    """``method``'s tiny scene written under ``work/<method>/`` and loaded (the
    environment-lit methods under ``work/sky.exr``)."""
    from pipeline.scene.file import load_scene

    doc = small_scene_dict(size)
    doc["name"], doc["methods"], doc["settings"] = method, [method], SETTINGS[method]
    if method in ENVIRONMENT_LIT:
        sky = work / "sky.exr"
        if not sky.is_file():
            work.mkdir(parents=True, exist_ok=True)
            sky_map(sky)
        doc["lights"] = [{"type": "environment", "file": str(sky)}]
    (work / method).mkdir(parents=True, exist_ok=True)
    return load_scene(write_scene(work / method, doc))
