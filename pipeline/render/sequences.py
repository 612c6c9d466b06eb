"""Edit sequences more than one method renders (``prt render --frames SPEC``): the
environment turning about +y, the camera circling its look_at point, a glossy
material's γ swept over its range. A method's ``sequences`` function parses its spec
forms and calls these; each returns (kind, edited scenes, a label per frame, the path
of the edit in words).

Angles in degrees; frame i of N is 360°·i/N from the start.
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import PrtError
from pipeline.method import NotApplicable
from pipeline.scene.edits import (
    with_camera_position,
    with_environment_rotation,
    with_material_edits,
)
from pipeline.scene.model import Scene

Sequence = tuple[str, list[Scene], list[str], str]


def turns(count: int) -> np.ndarray:
    """The N angles (degrees) of one full turn in equal steps, from 0."""
    return 360.0 * np.arange(count) / count


def rotate(scene: Scene, count: int) -> Sequence:
    """The environment map turns once about +y from the scene's rotation."""
    start = scene.environment.rotation
    angles = [start + a for a in turns(count)]
    return ("rotate", [with_environment_rotation(scene, a) for a in angles],
            [f"environment rotation {a:.4g}°" for a in angles],
            f"the environment map turns about +y from {start:g}° in {count} steps of "
            f"{360 / count:.4g}°")


def orbit(scene: Scene, count: int) -> Sequence:
    """The camera circles its look_at point once about +y (radius and height kept)."""
    cam = scene.camera
    offset = np.subtract(cam.position, cam.look_at)
    positions = []
    for a in np.radians(turns(count)):
        c, s = np.cos(a), np.sin(a)
        turned = (c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2])
        positions.append(tuple(np.add(cam.look_at, turned)))
    return ("orbit", [with_camera_position(scene, p) for p in positions],
            [f"camera at ({p[0]:.4g}, {p[1]:.4g}, {p[2]:.4g})" for p in positions],
            f"the camera circles its look_at point about +y at radius "
            f"{float(np.hypot(offset[0], offset[2])):.4g} scene units in {count} steps of "
            f"{360 / count:.4g}°")


def gamma_sweep(scene: Scene, name: str | None, count: int, how: str = "") -> Sequence:
    """Material ``name``'s γ (default: the first glossy material) geometrically over its
    ``gamma_range``, else [γ/4, 4γ]; one frame: its γ. ``how`` ends the path's words
    (how the method follows the edit). NotApplicable when the scene has no glossy
    material and none is named."""
    glossy = [n for n, m in scene.materials.items() if m.model != "lambert"]
    if not glossy and name is None:
        raise NotApplicable(scene.path, "a gamma sequence needs a glossy material; the "
                            "scene has none")
    name = name or glossy[0]
    if name not in glossy:
        raise PrtError(scene.path, f"a gamma sequence needs a glossy material (found "
                       f"{name!r}; glossy: {', '.join(glossy) or 'none'})")
    params = scene.materials[name].params
    lo, hi = params.get("gamma_range") or (params["gamma"] / 4, params["gamma"] * 4)
    gammas = np.geomspace(lo, hi, count) if count > 1 else [params["gamma"]]
    edits = [f"{name}.gamma={g:.6g}" for g in gammas]
    return ("gamma", [with_material_edits(scene, [e]) for e in edits], edits,
            f"material {name!r}: gamma from {gammas[0]:.4g} to {gammas[-1]:.4g}, {count} "
            f"frame(s) in geometric steps{how}")
