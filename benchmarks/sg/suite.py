"""Method sg on its scene suite (benchmarks/scene_suite.py): per scene and budget the
error against its transport and against full path tracing, frame times at 256² and
1024×768, storage and bake time."""

from __future__ import annotations

from typing import Any

from benchmarks.fixtures import SCENES, TINY
from benchmarks.scene_suite import (
    BUNNY_CLOSEUP,
    SUITE_SCENES,
    SuiteScene,
    scene_suite,
    tiny_preset,
)

UFFIZI = [{"type": "environment", "file": "${PRT_DATA}/envmaps/uffizi_256x128.hdr",
           "rotation": 0, "scale": 1.0}]
# sg renders light per vertex: the suite's teapot scene gets sg's 64 × 64 ground
SG_GROUND = {"primitive": {"type": "plane", "size": [6, 6], "segments": 64},
             "transform": {"translate": [0, -0.7685, 0]}, "material": "ground"}
TEAPOT = {"mesh": "${PRT_DATA}/meshes/teapot_6.3kf_open.obj", "smooth": True,
          "transform": {"scale": 0.3, "translate": [-0.065, -0.7685, 0]},
          "material": "teapot"}
DRAGON_COARSE = {  # scenes/dragon_sg.yaml's objects, the dragon not subdivided
    "dragon": {"mesh": "${PRT_DATA}/meshes/dragon_23kf.ply",
               "transform": {"scale": [0.01, 0.01, 0.01], "translate": [0.104, 6.7249, -2.982]},
               "material": "jade"},
    "ground": {"primitive": {"type": "plane", "size": [6, 6], "segments": 64},
               "transform": {"translate": [0, -0.7685, 0]}, "material": "grey"}}
SCENE_SUITE = (
    SuiteScene("bunny_sg", SCENES / "bunny_sg.yaml", "shipped: the scene it was tuned on"),
    SuiteScene("dragon_sg", SCENES / "dragon_sg.yaml",
               "shipped: folds and a studio map of two small lights; the dragon split once "
               "at its edges (objects.dragon.subdivide: 1, decision 0048)"),
    SuiteScene("dragon_sg_coarse", SCENES / "dragon_sg.yaml",
               "the dragon as its file has it (11k vertices): folds finer than the "
               "vertices (its visibility-folds limit warns)", {"objects": DRAGON_COARSE}),
    SuiteScene("bunny_sg_closeup", SCENES / "bunny_sg.yaml",
               "a close-up camera: half the distance", {"camera": BUNNY_CLOSEUP}),
    SuiteScene("bunny_sg_uffizi", SCENES / "bunny_sg.yaml", "not tuned on: another map",
               {"lights": UFFIZI}),
    SuiteScene("teapot_sunset_sg", SUITE_SCENES / "teapot_sunset.yaml",
               "not tuned on: another mesh; a small bright source (Venice's low sun)",
               {"methods": ["sg"], "objects": {"teapot": TEAPOT, "ground": SG_GROUND}}),
)
TINY_SUITE = (SuiteScene("tiny_sg", TINY / "tiny_sg.yaml", "smoke"),)
SWEEP = {"sg.diffuse_order": [4, 6, 8]}
PRESETS = {"default": [], "tiny": tiny_preset("sg.diffuse_order=2")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return scene_suite("sg.suite", "sg", {"full": SCENE_SUITE, "tiny": TINY_SUITE}, SWEEP,
                       argv)
