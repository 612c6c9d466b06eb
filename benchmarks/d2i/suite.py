"""Method d2i on its scene suite (benchmarks/scene_suite.py): per scene and budget the
error against its transport and against full path tracing, frame times at 256² and
1024×768, storage and bake time (d2i bakes per pixel: each frame size is a bake)."""

from __future__ import annotations

from typing import Any

from benchmarks.fixtures import SCENES, TINY
from benchmarks.scene_suite import SUITE_SCENES, SuiteScene, scene_suite, tiny_preset

CLOSEUP = {"position": [330, 160, 20], "look_at": [230, 110, 300], "up": [0, 1, 0],
           "fov": 39.3077, "width": 64, "height": 64}
# the luminaire a quarter as wide and deep, 16 × as bright (the same power), just below
# the luminaire's mesh (now not emitting)
SMALL_LIGHT = [{"type": "quad", "corner": [294.25, 547.5, 266.375], "edge_u": [0, 0, 26.25],
                "edge_v": [-32.5, 0, 0], "radiance": [294.19, 175.80, 44.06],
                "samples": 16}]
SCENE_SUITE = (
    SuiteScene("cornell_box", SCENES / "cornell_box.yaml", "shipped: the scene it was tuned on"),
    SuiteScene("cornell_closeup", SCENES / "cornell_box.yaml",
               "a close-up camera: the boxes and glossy floor from near", {"camera": CLOSEUP}),
    SuiteScene("cornell_small_light", SCENES / "cornell_box.yaml",
               "a small bright source: the luminaire's power from 1/16 of its area",
               {"lights": SMALL_LIGHT}),
    SuiteScene("dragon_room", SUITE_SCENES / "dragon_room.yaml",
               "not tuned on: Ward dragon, Blinn-Phong bunny, a spot light"),
)
TINY_SUITE = (SuiteScene("tiny_d2i", TINY / "tiny_d2i.yaml", "smoke"),)
SWEEP = {"gather.count": [1024, 4096]}  # and the default, 16384
PRESETS = {"default": [], "tiny": tiny_preset("gather.count=32")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return scene_suite("d2i.suite", "d2i", {"full": SCENE_SUITE, "tiny": TINY_SUITE}, SWEEP,
                       argv, bake_per_size=True)  # its G-buffer and rows are per pixel
