"""Method triple's hooks named by its descriptor (``__init__.py``): what it needs of a
scene (``check_scene``) and its edit sequences (``sequence``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.render import sequences
from pipeline.render.sequences import Sequence
from pipeline.scene.file import check_one_environment
from pipeline.scene.model import Scene

SEQUENCE_KINDS = ("rotate", "orbit", "gamma")


def check_scene(scene: Scene, params: Mapping[str, Any]) -> None:
    """Exactly one environment light, whose map reads as a valid latitude-longitude map."""
    check_one_environment(scene, "triple")


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str) -> Sequence:
    """The edit kind, edited scenes, a label per frame and the path in words
    (pipeline/render/sequences.py)."""
    parts = spec.split(":")
    kind, count_text = parts[0], parts[-1]
    if kind not in SEQUENCE_KINDS or len(parts) not in (2, 3) or not count_text.isdigit() \
            or int(count_text) < 1 or (len(parts) == 3 and kind != "gamma"):
        raise PrtError(None, f"--frames {spec}: expected rotate:N, orbit:N or "
                       "gamma[:MATERIAL]:N (N ≥ 1 frames)")
    count = int(count_text)
    if kind == "gamma":
        return sequences.gamma_sweep(scene, parts[1] if len(parts) == 3 else None, count,
                                     ", each table re-sampled at run time")
    return sequences.rotate(scene, count) if kind == "rotate" else sequences.orbit(scene, count)
