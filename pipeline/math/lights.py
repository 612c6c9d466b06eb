"""Direct lighting from point, spot, directional and quad area lights (NumPy).

The same formulas live in ``kernels/lights.h``; tests hold the two together.

Lights are packed as rows of :data:`LIGHT_FLOATS` float32 values; :class:`LightRow`
says where each field lies (the one definition of the layout: ``kernels/lights.h`` gets
the same offsets as ``-D LIGHT_<FIELD>`` defines from :func:`light_defines`)::

    TYPE           0 point, 1 spot, 2 directional, 3 quad
    POSITION       position (point, spot) or corner (quad; alias CORNER)
    DIRECTION      unit direction the light travels (spot axis, directional) or edge_u
                   (quad; alias EDGE_U)
    EDGE_V         edge_v (quad)
    RGB            intensity W/sr (point, spot), irradiance W/m² (directional),
                   radiance W/(m² sr) (quad)
    COS_OUTER, COS_INNER   cos of the outer and inner cone half-angles (spot)
    SAMPLES        shadow samples per pixel (quad: m², others 1)
    OBJECT         emitting object id (quad), -1 if none
    SAMPLE_OFFSET  offset of the light's samples in a pixel's visibility row

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

LIGHT_FLOATS = 20  # floats per packed light row (18 used, the rest padding)
TYPE_CODES = {"point": 0, "spot": 1, "directional": 2, "quad": 3}


class LightRow:
    """Where each field of a packed light row lies: an int for a scalar, a slice for a
    vector (``row[LightRow.POSITION]`` is (3,), ``packed[:, LightRow.SAMPLES]`` (L,)).
    CORNER and EDGE_U name the quad's use of POSITION and DIRECTION."""

    TYPE = 0
    POSITION = slice(1, 4)
    DIRECTION = slice(4, 7)
    EDGE_V = slice(7, 10)
    RGB = slice(10, 13)
    COS_OUTER = 13
    COS_INNER = 14
    SAMPLES = 15
    OBJECT = 16
    SAMPLE_OFFSET = 17
    CORNER = POSITION
    EDGE_U = DIRECTION


def light_fields() -> dict[str, tuple[int, int]]:
    """Every field of :class:`LightRow` (aliases included): name -> (offset, width)."""
    out = {}
    for name, at in vars(LightRow).items():
        if isinstance(at, slice):
            out[name] = (at.start, at.stop - at.start)
        elif isinstance(at, int) and name.isupper():
            out[name] = (at, 1)
    return out


def light_defines() -> dict[str, int]:
    """The ``-D`` defines that kernels including ``kernels/lights.h`` are built with:
    ``LIGHT_FLOATS``, ``LIGHT_<FIELD>`` (each field's offset) and ``LIGHT_<TYPE>`` (the
    type codes)."""
    defines = {"LIGHT_FLOATS": LIGHT_FLOATS}
    defines.update({f"LIGHT_{name}": offset for name, (offset, _) in light_fields().items()})
    defines.update({f"LIGHT_{kind.upper()}": code for kind, code in TYPE_CODES.items()})
    return defines


def pack_lights(lights: list[tuple[str, dict]], object_ids: dict[str, int]) -> np.ndarray:
    """Pack (type, params) pairs (scene light fields) into (L, LIGHT_FLOATS) float32."""
    f = LightRow
    rows = []
    offset = 0
    for kind, p in lights:
        row = np.zeros(LIGHT_FLOATS, np.float64)
        row[f.TYPE] = TYPE_CODES[kind]
        row[f.OBJECT] = -1
        if kind in ("point", "spot"):
            row[f.POSITION] = p["position"]
            row[f.RGB] = p["intensity"]
        if kind in ("spot", "directional"):
            d = np.asarray(p["direction"], float)
            row[f.DIRECTION] = d / np.linalg.norm(d)
        if kind == "spot":
            outer = math.radians(p["angle"])
            row[f.COS_OUTER] = math.cos(outer)
            row[f.COS_INNER] = math.cos(outer * (1.0 - p.get("falloff", 0.2)))
        if kind == "directional":
            row[f.RGB] = p["irradiance"]
        samples = 1
        if kind == "quad":
            row[f.CORNER], row[f.EDGE_U], row[f.EDGE_V] = p["corner"], p["edge_u"], p["edge_v"]
            row[f.RGB] = p["radiance"]
            samples = p.get("samples", 16)
            row[f.OBJECT] = object_ids.get(p.get("object", ""), -1)
        row[f.SAMPLES] = samples
        row[f.SAMPLE_OFFSET] = offset
        offset += samples
        rows.append(row)
    return np.asarray(rows, np.float32).reshape(-1, LIGHT_FLOATS)


def total_samples(packed: np.ndarray) -> int:
    """Visibility entries per pixel."""
    return int(packed[:, LightRow.SAMPLES].sum()) if len(packed) else 0


def light_sample_points(packed: np.ndarray, index: int, pixel: np.ndarray) -> np.ndarray:
    """Points sampled on light ``index`` for each pixel id: (N, samples, 3) float32.
    Point and spot lights give their position; directional lights give nothing useful
    (callers trace along −direction instead)."""
    f = LightRow
    row = packed[index]
    if row[f.TYPE] != TYPE_CODES["quad"]:
        return np.broadcast_to(row[f.POSITION], (len(pixel), 1, 3)).astype(np.float32)
    uv = stratified_square(pixel, index, int(row[f.SAMPLES]))
    return (row[f.CORNER] + uv[..., :1] * row[f.EDGE_U] + uv[..., 1:] * row[f.EDGE_V]
            ).astype(np.float32)


def quad_normal(row: np.ndarray) -> np.ndarray:
    """A quad light's edge_u × edge_v: its normal scaled by its area."""
    return np.cross(row[LightRow.EDGE_U], row[LightRow.EDGE_V])


def smoothstep(e0: np.ndarray, e1: np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def shade_direct(position: np.ndarray, normal: np.ndarray, pixel: np.ndarray,
                 brdf: Callable[[np.ndarray], np.ndarray], packed: np.ndarray,
                 visibility: np.ndarray) -> np.ndarray:
    """Outgoing radiance (N, 3) of points ``position``, ``normal`` (N, 3), ``pixel`` ids
    (N,), ``visibility`` (N, total_samples). ``brdf`` maps unit world directions towards
    the light (N, S, 3) to BRDF values (N, S, 3) of each point towards its viewer."""
    f = LightRow
    p = position.astype(np.float64)
    n = normal.astype(np.float64)
    out = np.zeros_like(p)
    for i, row in enumerate(packed.astype(np.float64)):
        kind, off, count = int(row[f.TYPE]), int(row[f.SAMPLE_OFFSET]), int(row[f.SAMPLES])
        vis = visibility[:, off:off + count].astype(np.float64)
        if kind == TYPE_CODES["directional"]:
            to_light = np.broadcast_to(-row[f.DIRECTION], (len(p), 1, 3))
            g = np.maximum(0.0, n @ -row[f.DIRECTION])[:, None] * vis
        else:
            q = light_sample_points(packed, i, pixel).astype(np.float64)
            d = q - p[:, None, :]
            r2 = np.sum(d * d, axis=-1)
            to_light = d / np.sqrt(r2)[..., None]
            g = np.maximum(0.0, np.einsum("nk,nsk->ns", n, to_light)) / r2 * vis
            if kind == TYPE_CODES["quad"]:
                nq = quad_normal(row)
                area = np.linalg.norm(nq)
                g = g * np.maximum(0.0, -(to_light @ (nq / area))) * area / count
            elif kind == TYPE_CODES["spot"]:
                g = g * smoothstep(row[f.COS_OUTER], row[f.COS_INNER],
                                   -(to_light @ row[f.DIRECTION]))
        out += row[f.RGB] * np.sum(brdf(to_light) * g[..., None], axis=1)
    return out


def quad_emission(object_id: np.ndarray, view: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """Radiance (N, 3) seen directly on quad lights' emitting objects (front side only);
    ``view`` (N, 3) are unit directions from the camera to the points."""
    f = LightRow
    out = np.zeros((len(object_id), 3))
    for row in packed.astype(np.float64):
        if int(row[f.TYPE]) == TYPE_CODES["quad"] and row[f.OBJECT] >= 0:
            front = (object_id == int(row[f.OBJECT])) & (view @ quad_normal(row) < 0.0)
            out[front] += row[f.RGB]
    return out
