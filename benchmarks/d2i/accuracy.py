"""Method d2i's error against cost on scenes/cornell_box.yaml: ``prt evaluate``'s sweep
(benchmarks/fixtures.py ``method_accuracy``)."""

from __future__ import annotations

from typing import Any

from benchmarks.fixtures import SCENES, TINY, method_accuracy

PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_d2i.yaml"), "--size", "8", "--repeats", "1",
                    "--reference-max-spp", "8", "--sweep", "gather.count=64"]}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return method_accuracy("d2i.accuracy", "d2i", argv, SCENES / "cornell_box.yaml")
