"""Method triple's error against cost on scenes/bunny_grace.yaml: ``prt evaluate``'s sweep
(benchmarks/fixtures.py ``method_accuracy``)."""

from __future__ import annotations

from typing import Any

from benchmarks.fixtures import SCENES, TINY, method_accuracy

PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_triple.yaml"), "--size", "8", "--repeats", "1",
                    "--reference-max-spp", "8", "--sweep", "render.budget=20"]}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return method_accuracy("triple.accuracy", "triple", argv, SCENES / "bunny_grace.yaml")
