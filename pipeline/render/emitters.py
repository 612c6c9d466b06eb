"""Quad lights seen where they are, after a run-time move (a light sequence).

A quad light's ``object`` is its emitter geometry (the Cornell box's luminaire). That
geometry is baked into the G-buffer and the transport, so it cannot move at run time.
While the light lies on its object's baked geometry (every corner of the parallelogram
within :data:`ON_OBJECT` × its diagonal of the object's bounding box), the G-buffer's
pixels of the object show the light's radiance (kernels/lights.h ``quad_emission``).
Once the light has moved off it:

* the baked object no longer emits: its pixels show its surface, lit like any other
  (the light is packed without its object), and
* the pixels whose camera ray meets the moved parallelogram from its front, no farther
  than the G-buffer's surface, show the light's radiance: the visible luminaire moves
  with its light. Ties go to the emitter (a luminaire moved within its own plane).

Shadows and transport still see the baked object at its old place (on the Cornell box,
a thin panel on the ceiling, which blocks no light that reaches the room). A light
without an ``object`` has no geometry: nothing is drawn for it, moved or not.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.math.camera import camera_rays
from pipeline.scene.model import Camera, Scene

ON_OBJECT = 0.05  # corners this far (× the quad's diagonal) from the object's box: on it
TIE = 1e-4  # relative depth within which the moved emitter wins over the G-buffer

Bounds = Mapping[str, tuple[np.ndarray, np.ndarray]]  # object -> (min, max) corners


def object_bounds(names: list[str], vertices: np.ndarray, ranges: np.ndarray
                  ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each object's axis-aligned bounding box (min, max) from the geometry artifact's
    ``vertices`` and ``object_ranges`` (scene units, world frame)."""
    out = {}
    for name, (v0, v1, _, _) in zip(names, ranges, strict=True):
        if v1 > v0:
            points = vertices[v0:v1].astype(np.float64)
            out[name] = (points.min(axis=0), points.max(axis=0))
    return out


def quad_corners(params: Mapping[str, Any]) -> np.ndarray:
    """(4, 3) corners of a quad light's parallelogram."""
    c, eu, ev = (np.asarray(params[k], np.float64) for k in ("corner", "edge_u", "edge_v"))
    return np.array([c, c + eu, c + ev, c + eu + ev])


def moved_quads(scene: Scene, bounds: Bounds) -> list[int]:
    """Indices of ``scene``'s quad lights with an ``object`` they no longer lie on."""
    out = []
    for i, light in enumerate(scene.lights):
        name = light.params.get("object") if light.type == "quad" else None
        if not name or name not in bounds:
            continue
        corners = quad_corners(light.params)
        lo, hi = bounds[name]
        outside = np.maximum(np.maximum(lo - corners, corners - hi), 0.0)
        size = np.linalg.norm(corners[3] - corners[0])
        if np.linalg.norm(outside, axis=1).max() > ON_OBJECT * size:
            out.append(i)
    return out


def unbound_lights(scene: Scene, moved: list[int]) -> list[tuple[str, dict[str, Any]]]:
    """(type, params) of ``scene``'s lights, the ``moved`` ones without their object (so
    the baked geometry stops emitting)."""
    return [(light.type, {k: v for k, v in light.params.items()
                          if not (i in moved and k == "object")})
            for i, light in enumerate(scene.lights)]


class EmitterOverlay:
    """Draws moved quad lights over frames of one baked view: the camera rays of the
    pixel centres, the depth of each pixel's G-buffer surface (inf where none) and the
    emitter objects' bounds."""

    def __init__(self, camera: Camera, position: np.ndarray, material_id: np.ndarray,
                 bounds: Bounds) -> None:
        _, direction = camera_rays(camera.position, camera.look_at, camera.up, camera.fov,
                                   camera.width, camera.height)
        self.bounds = bounds
        self.origin = np.asarray(camera.position, np.float64)
        self.direction = direction.reshape(-1, 3).astype(np.float64)
        dist = np.linalg.norm(position.astype(np.float64) - self.origin, axis=1)
        self.depth = np.where(material_id >= 0, dist, np.inf)

    def moved(self, scene: Scene) -> list[int]:
        """The quad lights of ``scene`` moved off their emitter objects."""
        return moved_quads(scene, self.bounds)

    def draw(self, rgb: np.ndarray, scene: Scene) -> np.ndarray:
        """``rgb`` (P, 3) with each moved quad light of ``scene`` drawn in its radiance
        where it is the nearest surface; ``rgb`` itself when no light moved."""
        moved = self.moved(scene)
        if not moved:
            return rgb
        out = np.array(rgb, copy=True)
        for i in moved:
            p = scene.lights[i].params
            out[self.covered(p["corner"], p["edge_u"], p["edge_v"])] = p["radiance"]
        return out

    def covered(self, corner: Any, edge_u: Any, edge_v: Any) -> np.ndarray:
        """(P,) bool: the pixels whose ray meets the front (the side edge_u × edge_v
        faces) of the parallelogram corner + u·edge_u + v·edge_v, u, v ∈ [0, 1], before
        (or at, within :data:`TIE`) their G-buffer surface."""
        c, eu, ev = (np.asarray(v, np.float64) for v in (corner, edge_u, edge_v))
        n = np.cross(eu, ev)
        facing = self.direction @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(facing < 0, ((c - self.origin) @ n) / facing, -1.0)
        rel = self.origin + t[:, None] * self.direction - c
        u = rel @ np.cross(ev, n) / (eu @ np.cross(ev, n))
        v = rel @ np.cross(n, eu) / (ev @ np.cross(n, eu))
        inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        return inside & (t > 0) & (t <= self.depth * (1 + TIE))
