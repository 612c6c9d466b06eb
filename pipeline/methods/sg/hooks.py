"""Method sg's hooks named by its descriptor (``__init__.py``): what it needs of a
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


def check_scene(scene: Scene, params: Mapping[str, Any]) -> None:
    """Exactly one environment light, whose map reads as a valid latitude-longitude map,
    and glossy lobes the fit's grid can sample (checked before anything is baked)."""
    check_one_environment(scene, "sg")
    check_lobe_widths(scene, params["sg.fit_grid"])


def check_lobe_widths(scene: Scene, fit_grid: list[int]) -> None:
    """PrtError naming the material when a glossy lobe is too sharp for the fit's grid.

    sg.fit tabulates each vertex's transport on the lat-long grid ``sg.fit_grid`` =
    [rows, columns] (pole +y): samples Δθ = π/(rows − 1) and Δφ = 2π/columns apart, so a
    direction lies up to d = ½ √(Δθ² + Δφ²) from the nearest sample (on the equator).
    A lobe whose half width at half maximum (at normal view, measured on the BRDF) is
    under d/2 can fall between the samples: its tabulation is a fraction of its peak, or
    zero (γ 20000 on a [9, 18] grid divided by a zero norm mid-bake)."""
    import math

    import numpy as np

    from pipeline.math.brdf import glossy, scene_brdfs

    rows, columns = (int(n) for n in fit_grid)
    spacing = 0.5 * math.hypot(math.pi / max(rows - 1, 1), 2 * math.pi / max(columns, 1))
    used = sorted({o.material for o in scene.objects.values()})
    t = np.geomspace(1e-5, math.pi / 2, 4000)
    wi = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)  # away from the normal
    wo = np.array([0.0, 0.0, 1.0])
    for name, brdf in zip(used, scene_brdfs(scene, used), strict=True):
        if brdf.model == "lambert" or max(brdf.specular) <= 0:
            continue
        lobe = glossy(wi, wo, brdf)
        below = np.flatnonzero(lobe < 0.5 * lobe[0])
        width = t[below[0]] if len(below) else math.pi / 2
        if width < 0.5 * spacing:
            raise PrtError(scene.path, f"materials.{name}: its glossy lobe (half width "
                           f"{math.degrees(width):.2g}° at normal view) is too sharp for "
                           f"sg.fit_grid {[rows, columns]}, whose samples lie up to "
                           f"{math.degrees(spacing):.2g}° apart: give a broader lobe (a "
                           f"smaller gamma) or a finer sg.fit_grid (about "
                           f"{_rows_for(width)} rows)")


def _rows_for(width: float) -> int:
    """The rows (columns = 2 × rows) whose largest distance to a sample is 2 × ``width``
    radians: d = ½ √(Δθ² + Δφ²) with Δθ ≈ Δφ ≈ π/(rows − 1) gives rows ≈ π/(2√2 w) + 1."""
    import math

    return math.ceil(math.pi / (2 * math.sqrt(2) * width)) + 1


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str) -> Sequence:
    """``rotate:N`` (the environment turns about +y) or ``orbit:N`` (the camera circles
    its look_at point; pipeline/render/sequences.py)."""
    kind, _, count = spec.partition(":")
    if kind not in ("rotate", "orbit") or not count.isdigit() or int(count) < 1:
        raise PrtError(None, f"--frames {spec}: expected rotate:N or orbit:N (N ≥ 1 frames)")
    return (sequences.rotate if kind == "rotate" else sequences.orbit)(scene, int(count))
