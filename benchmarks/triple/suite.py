"""Method triple on its scene suite (benchmarks/scene_suite.py): per scene and budget the
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

SCENE_SUITE = (
    SuiteScene("bunny_grace", SCENES / "bunny_grace.yaml", "shipped: the scene it was tuned on"),
    SuiteScene("dragon_pisa", SCENES / "dragon_pisa.yaml",
               "shipped: a detailed mesh in a small atlas (its limits warn)"),
    SuiteScene("bunny_grace_closeup", SCENES / "bunny_grace.yaml",
               "a close-up camera: half the distance", {"camera": BUNNY_CLOSEUP}),
    SuiteScene("armadillo_forest", SUITE_SCENES / "armadillo_forest.yaml",
               "not tuned on: another mesh, anisotropic Ward, a glossy ground, an outdoor sky"),
    SuiteScene("teapot_sunset", SUITE_SCENES / "teapot_sunset.yaml",
               "a small bright source: Venice's low sun"),
)
TINY_SUITE = (SuiteScene("tiny_triple", TINY / "tiny_triple.yaml", "smoke"),)
SWEEP = {"render.budget": [80, 320, 0]}
PRESETS = {"default": [], "tiny": tiny_preset("render.budget=20")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return scene_suite("triple.suite", "triple", {"full": SCENE_SUITE, "tiny": TINY_SUITE},
                       SWEEP, argv)
