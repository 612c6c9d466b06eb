"""Method sg's error against cost on scenes/bunny_sg.yaml: ``prt evaluate``'s sweep
(benchmarks/fixtures.py ``method_accuracy``)."""

from __future__ import annotations

from typing import Any

from benchmarks.fixtures import SCENES, TINY, method_accuracy

PRESETS = {"default": [],
           "tiny": ["--scene", str(TINY / "tiny_sg.yaml"), "--size", "8", "--repeats", "1",
                    "--reference-max-spp", "8", "--sweep", "sg.fit_max_lobes=1"]}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return method_accuracy("sg.accuracy", "sg", argv, SCENES / "bunny_sg.yaml")
