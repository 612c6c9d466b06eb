"""Direct lighting from point, spot, directional and quad area lights (NumPy).

The same formulas live in ``kernels/lights.h``; tests hold the two together.

Lights are packed as rows of :data:`LIGHT_FLOATS` float32 values::

    [0]      type: 0 point, 1 spot, 2 directional, 3 quad
    [1:4]    position (point, spot) or corner (quad)
    [4:7]    unit direction the light travels (spot axis, directional) or edge_u (quad)
    [7:10]   edge_v (quad)
    [10:13]  RGB: intensity W/sr (point, spot), irradiance W/m² (directional),
             radiance W/(m² sr) (quad)
    [13:15]  cos of the outer and inner cone half-angles (spot)
    [15]     shadow samples per pixel (quad: m², others 1)
    [16]     emitting object id (quad), -1 if none
    [17]     offset of the light's samples in a pixel's visibility row

Radiance leaving a surface point x with unit normal n towards the viewer, with BRDF
f(l) = f(l, ω_view) (pipeline/math/brdf.py)::

    point:       f(l) · I · max(0, n·l) / r² · V
    spot:        the same × smoothstep(cos_outer, cos_inner, −l·axis)
    directional: f(−d) · E · max(0, −n·d) · V
    quad:        L_e · (A / N) Σ_s f(l_s) max(0, n·l_s) max(0, −n_q·l_s) / r_s² · V_s

with l the unit vector from x to the light (sample), r its distance, n_q the quad's unit
normal edge_u × edge_v, A its area and V ∈ {0, 1} the visibility found by shadow rays.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pipeline.math.sampling import stratified_square

LIGHT_FLOATS = 20
TYPE_CODES = {"point": 0, "spot": 1, "directional": 2, "quad": 3}


def pack_lights(lights: list[tuple[str, dict]], object_ids: dict[str, int]) -> np.ndarray:
    """Pack (type, params) pairs (scene light fields) into (L, LIGHT_FLOATS) float32."""
    rows = []
    offset = 0
    for kind, p in lights:
        row = np.zeros(LIGHT_FLOATS, np.float64)
        row[0] = TYPE_CODES[kind]
        row[16] = -1
        if kind in ("point", "spot"):
            row[1:4] = p["position"]
            row[10:13] = p["intensity"]
        if kind in ("spot", "directional"):
            d = np.asarray(p["direction"], float)
            row[4:7] = d / np.linalg.norm(d)
        if kind == "spot":
            outer = math.radians(p["angle"])
            row[13] = math.cos(outer)
            row[14] = math.cos(outer * (1.0 - p.get("falloff", 0.2)))
        if kind == "directional":
            row[10:13] = p["irradiance"]
        samples = 1
        if kind == "quad":
            row[1:4], row[4:7], row[7:10] = p["corner"], p["edge_u"], p["edge_v"]
            row[10:13] = p["radiance"]
            samples = p.get("samples", 16)
            row[16] = object_ids.get(p.get("object", ""), -1)
        row[15] = samples
        row[17] = offset
        offset += samples
        rows.append(row)
    return np.asarray(rows, np.float32).reshape(-1, LIGHT_FLOATS)


def total_samples(packed: np.ndarray) -> int:
    """Visibility entries per pixel."""
    return int(packed[:, 15].sum()) if len(packed) else 0


def light_sample_points(packed: np.ndarray, index: int, pixel: np.ndarray) -> np.ndarray:
    """Points sampled on light ``index`` for each pixel id: (N, samples, 3) float32.
    Point and spot lights give their position; directional lights give nothing useful
    (callers trace along −direction instead)."""
    row = packed[index]
    if row[0] != TYPE_CODES["quad"]:
        return np.broadcast_to(row[1:4], (len(pixel), 1, 3)).astype(np.float32)
    uv = stratified_square(pixel, index, int(row[15]))
    return (row[1:4] + uv[..., :1] * row[4:7] + uv[..., 1:] * row[7:10]).astype(np.float32)


def smoothstep(e0: np.ndarray, e1: np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def shade_direct(position: np.ndarray, normal: np.ndarray, pixel: np.ndarray,
                 brdf: Callable[[np.ndarray], np.ndarray], packed: np.ndarray,
                 visibility: np.ndarray) -> np.ndarray:
    """Outgoing radiance (N, 3) of points ``position``, ``normal`` (N, 3), ``pixel`` ids
    (N,), ``visibility`` (N, total_samples). ``brdf`` maps unit world directions towards
    the light (N, S, 3) to BRDF values (N, S, 3) of each point towards its viewer."""
    p = position.astype(np.float64)
    n = normal.astype(np.float64)
    out = np.zeros_like(p)
    for i, row in enumerate(packed.astype(np.float64)):
        kind, off, count = int(row[0]), int(row[17]), int(row[15])
        vis = visibility[:, off:off + count].astype(np.float64)
        if kind == TYPE_CODES["directional"]:
            to_light = np.broadcast_to(-row[4:7], (len(p), 1, 3))
            g = np.maximum(0.0, n @ -row[4:7])[:, None] * vis
        else:
            q = light_sample_points(packed, i, pixel).astype(np.float64)
            d = q - p[:, None, :]
            r2 = np.sum(d * d, axis=-1)
            to_light = d / np.sqrt(r2)[..., None]
            g = np.maximum(0.0, np.einsum("nk,nsk->ns", n, to_light)) / r2 * vis
            if kind == TYPE_CODES["quad"]:
                nq = np.cross(row[4:7], row[7:10])
                area = np.linalg.norm(nq)
                g = g * np.maximum(0.0, -(to_light @ (nq / area))) * area / count
            elif kind == TYPE_CODES["spot"]:
                g = g * smoothstep(row[13], row[14], -(to_light @ row[4:7]))
        out += row[10:13] * np.sum(brdf(to_light) * g[..., None], axis=1)
    return out


def quad_emission(object_id: np.ndarray, view: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """Radiance (N, 3) seen directly on quad lights' emitting objects (front side only);
    ``view`` (N, 3) are unit directions from the camera to the points."""
    out = np.zeros((len(object_id), 3))
    for row in packed.astype(np.float64):
        if int(row[0]) == TYPE_CODES["quad"] and row[16] >= 0:
            nq = np.cross(row[4:7], row[7:10])
            front = (object_id == int(row[16])) & (view @ nq < 0.0)
            out[front] += row[10:13]
    return out
