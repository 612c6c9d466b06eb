"""Method d2i's hooks named by its descriptor (``__init__.py``): what it needs of a
scene (``check_scene``) and its edit sequences (``sequence``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.method import NotApplicable
from pipeline.render import sequences
from pipeline.render.sequences import Sequence
from pipeline.scene.edits import with_light_offset
from pipeline.scene.model import Scene

SEQUENCE_KINDS = ("light", "gamma")
MOVABLE = ("point", "spot", "quad")  # light kinds with a position a light sequence moves


def check_scene(scene: Scene, params: Mapping[str, Any]) -> None:
    """Every glossy material needs the γ range its PCA basis is baked over."""
    for name, material in scene.materials.items():
        if material.model != "lambert" and "gamma_range" not in material.params:
            raise PrtError(scene.path, f"materials.{name}.gamma_range: method d2i needs the "
                           "range of gamma its PCA basis covers, e.g. [3, 300]")


def parse_sequence(text: str) -> tuple[str, str | None, int]:
    """``light[:LIGHT]:N`` or ``gamma[:MATERIAL]:N`` -> (kind, LIGHT or MATERIAL or None,
    N)."""
    parts = text.split(":")
    if parts[0] not in SEQUENCE_KINDS or len(parts) not in (2, 3) or \
            not parts[-1].isdigit() or int(parts[-1]) < 1 or \
            (len(parts) == 3 and not parts[1]):
        raise PrtError(None, f"--frames {text}: expected light[:LIGHT]:N or "
                       "gamma[:MATERIAL]:N (N ≥ 1 frames; LIGHT an index into lights or "
                       "a quad light's object)")
    return parts[0], parts[1] if len(parts) == 3 else None, int(parts[-1])


def pick_light(scene: Scene, name: str | None) -> int:
    """The index of the light a light sequence moves: ``name`` an index into ``lights``
    or the ``object`` of a quad light; default the first light with a position."""
    movable = [i for i, light in enumerate(scene.lights) if light.type in MOVABLE]
    if name is None:
        if not movable:
            kinds = ", ".join(sorted({light.type for light in scene.lights})) or "none"
            raise NotApplicable(scene.path, "a light sequence needs a light with a position "
                                f"(point, spot or quad) to move; the scene's lights: {kinds}")
        return movable[0]
    named = [i for i, light in enumerate(scene.lights)
             if name == str(i) or light.params.get("object") == name]
    if not named:
        raise PrtError(scene.path, f"--frames light:{name}: no light {name!r} (an index "
                       f"0..{len(scene.lights) - 1} or a quad light's object)")
    if named[0] not in movable:
        raise PrtError(scene.path, f"--frames light:{name}: lights[{named[0]}] is a "
                       f"{scene.lights[named[0]].type} light; it has no position to move")
    return named[0]


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str) -> Sequence:
    """The edit kind, edited scenes, a label for each frame of ``spec`` and the path of
    the edit in words.

    ``light``: the light (see :func:`pick_light`) moves around a horizontal circle (the
    world xz plane) centred on its position (a quad: its corner), of radius 0.1 × the
    diagonal of the scene's bounding box, frame i at angle 2πi/N from +x towards +z
    (frame 0 is displaced by the radius along +x). A quad light's emitter object is
    drawn where the light is (pipeline/render/emitters.py).
    ``gamma``: material M's γ geometrically over its gamma_range (N = 1: its γ)."""
    kind, name, count = parse_sequence(spec)
    if kind == "light":
        index = pick_light(scene, name)
        light = scene.lights[index]
        geo = artifacts["geometry"].attrs
        radius = 0.1 * float(np.linalg.norm(np.subtract(geo["bbox_max"], geo["bbox_min"])))
        angles = 2 * np.pi * np.arange(count) / count
        offsets = [(radius * np.cos(a), 0.0, radius * np.sin(a)) for a in angles]
        key = "corner" if light.type == "quad" else "position"
        centre = ", ".join(f"{v:.4g}" for v in light.params[key])
        emitter = f"its emitter {light.params['object']!r} moves with it" \
            if light.params.get("object") else "a light without geometry: nothing visible moves"
        path = (f"lights[{index}] ({light.type}; {emitter}) moves around a horizontal "
                f"circle (xz plane) of radius {radius:.4g} scene units centred on its "
                f"{key} ({centre}): {count} frame(s) {360 / count:.4g}° apart, frame 0 at "
                "+x, turning towards +z")
        return (kind, [with_light_offset(scene, index, o) for o in offsets],
                [f"light {index} moved by ({o[0]:.3g}, {o[1]:.3g}, {o[2]:.3g})"
                 for o in offsets], path)
    return sequences.gamma_sweep(scene, name, count)
