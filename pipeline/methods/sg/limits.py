"""Method sg's limits (pipeline/method.py ``Limit``): where its picture breaks down.

**Small bright sources.** The diffuse term is a spherical-harmonic transfer of order n
(``sg.diffuse_order``, n² coefficients per vertex): it resolves the lighting to cells of
about 4π/n² sr. A map whose light comes mostly from sources smaller than that casts
shadows the term cannot hold: they come out as one blurred, too-dark blob (dragon_sg
under the studio map: diffuse part 19.1 % off, decision 0038). Under ``normal=visibility``
(the default) the map's few bright sources of ``sg.source_min_share`` or more each are
taken apart and lit by what each vertex sees of them (decisions 0048, 0049), so what the
term must hold is the rest of the map: the check measures the share of the *residual*
map's power (luminance × solid angle) in its brightest texels covering one such cell,
and warns from :data:`MOST_SOURCE_SHARE` — many small sources, none large enough to be
taken apart. At n = 8: the studio map 0.89 whole, 0.48 less its two lights; Grace
Cathedral 0.55 (no source of 5 %); 1/n² for a uniform sky; the outdoor maps 0.12–0.34.

**Vertex spacing on screen.** Light is carried per vertex and interpolated across each
triangle, so nothing sharper than the mesh's edges on screen shows: the 453-vertex bunny
at 128² errs 13.5 % against 7.7 % for 3,301 vertices (docs/methods/sg.md). The check
projects every edge of the meshes in the camera's view and warns where their median
spans more than :data:`MOST_EDGE_PIXELS` pixels.

**Folds finer than the vertices.** Under ``normal=visibility`` the glossy light sees
each vertex's visibility map, interpolated across the triangle: where the surface folds
faster than its vertices (the dragon's scales), neighbouring vertices see very different
skies and a highlight's shadowing is smeared. The check takes, per object, the mean over
its edges of the two ends' visibility maps' difference (escape fractions, mean over the
finest level's texels) and warns from :data:`MOST_VISIBILITY_STEP`: bunny_sg's bunny
0.041 (glossy light 13.9 % off at 128²), dragon_sg's dragon 0.056 (21.0 %), the dragon
subdivided once 0.031 (12.8 %) (decision 0048); the remedy it names is
``objects.NAME.subdivide``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.math.envmap import LUMINANCE
from pipeline.scene.model import Scene

MOST_SOURCE_SHARE = 0.75  # of the map's power in its brightest 4π/n² sr
MOST_EDGE_PIXELS = 6.0  # median edge length on screen, pixels: 3 px 7.7 %, 8.4 px 13.5 %
MOST_VISIBILITY_STEP = 0.05  # mean visibility difference across an edge (module docstring)


@functools.lru_cache(maxsize=8)
def source_share(path: str, order: int, quantile: float, min_share: float) -> float:
    """The share of the power (luminance × solid angle) of the latitude-longitude map
    ``path`` less its bright sources (sources.py's split at ``quantile`` and
    ``min_share``) in its brightest texels that together cover 4π/``order``² sr."""
    from pipeline.images import read_environment
    from pipeline.methods.sg.sources import split_sources

    _, rgb = split_sources(read_environment(path), quantile, min_share)
    height, width = rgb.shape[:2]
    rows = (np.arange(height) + 0.5) / height
    solid_angle = np.broadcast_to((2 * np.pi ** 2 / (height * width))
                                  * np.sin(np.pi * rows)[:, None], (height, width)).ravel()
    luminance = np.clip(rgb @ LUMINANCE, 0.0, None).ravel()
    power = luminance * solid_angle
    if power.sum() <= 0:
        return 0.0
    brightest = np.argsort(luminance)[::-1]
    cell = np.searchsorted(np.cumsum(solid_angle[brightest]), 4 * np.pi / order ** 2) + 1
    return float(power[brightest[:cell]].sum() / power.sum())


def small_sources(scene: Scene, params: Mapping[str, Any],
                  artifacts: Mapping[str, Any] | None) -> str | None:
    """Whether the light the map's bright sources leave comes mostly from sources
    smaller than the diffuse term's SH cells (module docstring)."""
    env = scene.environment
    if env is None:
        return None
    order = int(params["sg.diffuse_order"])
    share = source_share(str(env.file), order, float(params["sg.source_quantile"]),
                         float(params["sg.source_min_share"]))
    if share < MOST_SOURCE_SHARE:
        return None
    return (f"{env.file.name} holds {100 * share:.0f} % of the light its sources of "
            f"{100 * float(params['sg.source_min_share']):g} % or more leave in its brightest "
            f"{4 * np.pi / order ** 2:.2f} sr ({100 / order ** 2:.1f} % of the sphere, one "
            f"cell of sg.diffuse_order {order}): the shadows of such small sources come out "
            "blurred and dark; a lower sg.source_min_share takes more of them apart, "
            "method triple keeps them all sharp")


def edge_pixels(vertices: np.ndarray, faces: np.ndarray, scene: Scene) -> np.ndarray:
    """The on-screen length in pixels of each edge of a mesh (world ``vertices`` (V, 3),
    ``faces`` (F, 3)) whose both ends lie in front of ``scene``'s camera and inside its
    view: its world length over the pixel footprint at its midpoint's depth."""
    cam = scene.camera
    eye, at = np.asarray(cam.position, float), np.asarray(cam.look_at, float)
    forward = (at - eye) / np.linalg.norm(at - eye)
    right = np.cross(forward, np.asarray(cam.up, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_half = np.tan(np.radians(cam.fov) / 2)
    rel = np.asarray(vertices, float) - eye
    depth = rel @ forward
    safe = np.maximum(depth, 1e-12)
    inside = (depth > 0) & (np.abs(rel @ up) / safe <= tan_half) \
        & (np.abs(rel @ right) / safe <= tan_half * cam.width / cam.height)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]],
                                              faces[:, [2, 0]]]), axis=1), axis=0)
    edges = edges[inside[edges].all(axis=1)]
    length = np.linalg.norm(rel[edges[:, 0]] - rel[edges[:, 1]], axis=1)
    footprint = 2 * tan_half * depth[edges].mean(axis=1) / cam.height  # world units/pixel
    return length / footprint


def vertex_spacing(scene: Scene, params: Mapping[str, Any],
                   artifacts: Mapping[str, Any] | None) -> str | None:
    """The objects whose edges span more than :data:`MOST_EDGE_PIXELS` pixels on screen
    (median over the edges in view)."""
    if artifacts is None:
        return None
    from pipeline.engine.chunkwrite import segment_name

    geometry = artifacts["geometry"]
    found = []
    for obj in geometry.attrs["object_names"]:
        def piece(name: str, obj: str = obj) -> np.ndarray:
            return np.asarray(geometry.group[name][segment_name(obj)][...])

        pixels = edge_pixels(piece("vertices"), piece("faces"), scene)
        if len(pixels) and float(np.median(pixels)) > MOST_EDGE_PIXELS:
            found.append(f"objects.{obj}: its edges span {np.median(pixels):.1f} pixels "
                         f"(median; light is carried per vertex and interpolated across "
                         f"each triangle, so nothing sharper shows): a finer mesh or a "
                         f"smaller image")
    return "; ".join(found) or None


def visibility_step(maps: np.ndarray, resolution: int, faces: np.ndarray) -> float:
    """The mean over the edges of ``faces`` (F, 3) (global vertex indices) of the mean
    absolute difference of their ends' finest visibility level (``maps`` (V, texels)
    uint8, sg.visibility's packed pyramids of ``resolution``² texels), in [0, 1]."""
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]],
                                              faces[:, [2, 0]]]), axis=1), axis=0)
    finest = resolution * resolution
    total = 0.0
    for start in range(0, len(edges), 65536):  # bounded memory on large meshes
        e = edges[start:start + 65536]
        a = maps[e[:, 0], :finest].astype(np.int16)
        b = maps[e[:, 1], :finest].astype(np.int16)
        total += float(np.abs(a - b).sum()) / (255.0 * finest)
    return total / max(len(edges), 1)


def visibility_folds(scene: Scene, params: Mapping[str, Any],
                     artifacts: Mapping[str, Any] | None) -> str | None:
    """The objects whose neighbouring vertices' visibility differs by more than
    :data:`MOST_VISIBILITY_STEP` on average (module docstring); only where the frame
    reads sg.visibility."""
    if artifacts is None or "sg.visibility" not in artifacts:
        return None
    geometry, visibility = artifacts["geometry"], artifacts["sg.visibility"]
    maps = np.asarray(visibility.read("maps"))
    resolution = int(params["sg.visibility_resolution"])
    faces = np.asarray(geometry.read("faces"), np.int64)
    face_object = np.asarray(geometry.read("face_object"))
    found = []
    for index, obj in enumerate(geometry.attrs["object_names"]):
        step = visibility_step(maps, resolution, faces[face_object == index])
        if step > MOST_VISIBILITY_STEP:
            found.append(f"objects.{obj}: neighbouring vertices' visibility differs by "
                         f"{100 * step:.1f} % of the sphere on average (folds finer than "
                         f"its vertices smear its highlights' shadows): objects.{obj}."
                         f"subdivide: 1 gives it 4× the vertices")
    return "; ".join(found) or None
