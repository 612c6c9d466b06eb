"""Method triple's limits (pipeline/method.py ``Limit``): where its picture breaks down,
checked on the baked atlas against the camera a frame is rendered from.

**Texels per pixel.** The atlas (stages/atlas.py) gives an object about t² covered
texels per pixel it covers on screen, t = ``triple.texels_per_pixel`` (3), for the
camera it was baked for. Seen from another camera, or at a run-time ``--size`` larger
than the baked one, the density is t' = √(covered texels / pixels now). Below
:data:`LEAST_TEXELS_PER_PIXEL` the texels show as blocks and contact shadows alias:
1 / 2 / 4 texels per pixel gave 10.6 / 6.6 / 3.8 % on the sun scene at 64², and a camera
2.5× closer 6.5 % against 3.75 % re-baked (docs/methods/triple.md, "Where it breaks").

**Atlas padding.** xatlas cuts a detailed mesh into many small charts, each with 2
texels of padding; in a small texture the padding can take most of it, so the covered
texels are far fewer than the size rule planned (the 23k-face dragon at 96² and 1 texel
per pixel: 49 of 20,022 texels covered, 26.8 % off and 16 % dark). Below
:data:`LEAST_COVERED_FRACTION` covered, the check warns.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.scene.model import Scene

LEAST_TEXELS_PER_PIXEL = 1.5  # between 1 (10.6 %) and 2 (6.6 %) texels per pixel
LEAST_COVERED_FRACTION = 0.25  # "mostly padding": over three quarters of the texture
CLOSER = 1.2  # an object this many times more pixels than baked: the camera came closer
CAPPED = 0.8  # a texture side this near triple.texture_max was capped (packing rounds)


def texels_per_pixel(scene: Scene, params: Mapping[str, Any],
                     artifacts: Mapping[str, Any] | None) -> str | None:
    """The objects whose texels are larger than :data:`LEAST_TEXELS_PER_PIXEL` allows
    from ``scene``'s camera, with the cause (a closer camera or larger image than baked,
    the texture capped at ``triple.texture_max``, or too low a density setting)."""
    if artifacts is None:
        return None
    atlas, geometry = artifacts["triple.atlas"], artifacts["geometry"]
    attrs = atlas.attrs
    camera = dataclasses.asdict(scene.camera)
    found = []
    for obj, counts in attrs["texel_counts"].items():
        pixels = _screen_pixels(geometry, obj, camera)
        if pixels == 0:
            continue
        density = float(np.sqrt(counts["covered"] / pixels))
        if density >= LEAST_TEXELS_PER_PIXEL:
            continue
        baked = attrs["screen_pixels"][obj]
        if pixels > CLOSER * baked:
            cause = (f"it covers {pixels / max(baked, 1):.1f}× the pixels it covered for the "
                     "camera the atlas was baked for (the scene file's: prt render and "
                     "prt view render other cameras and sizes from its bake, decision "
                     "0045): give the file this camera to bake for it")
        elif max(attrs["texture_sizes"][obj]) >= CAPPED * attrs["texture_max"]:
            cause = (f"its texture is capped at triple.texture_max "
                     f"{attrs['texture_max']}: raise it")
        else:
            cause = f"raise triple.texels_per_pixel ({attrs['texels_per_pixel']:g})"
        shown = np.floor(density * 100) / 100  # 1.4975 reads 1.49, not 1.50 "below 1.5"
        found.append(f"objects.{obj}: {shown:.2f} texels per pixel (below "
                     f"{LEAST_TEXELS_PER_PIXEL}: texel blocks and aliased contact shadows); "
                     f"{cause}")
    return "; ".join(found) or None


def _screen_pixels(geometry: Any, obj: str, camera: dict[str, Any]) -> int:
    """stages/atlas.py's screen_pixels of object ``obj`` from ``camera``, remembered
    for the last few (geometry, object, camera): a sequence that turns the map checks
    every frame's scene, and each check would trace the whole image again."""
    key = (str(geometry.path), geometry.record.get("key"), obj,
           tuple((k, tuple(v) if isinstance(v, list | tuple) else v)
                 for k, v in sorted(camera.items())))
    if key not in _SEEN:
        from pipeline.methods.triple.stages.atlas import object_piece, screen_pixels

        if len(_SEEN) >= 16:
            _SEEN.pop(next(iter(_SEEN)))
        _SEEN[key] = screen_pixels(object_piece(geometry, "vertices", obj),
                                   object_piece(geometry, "faces", obj), camera)
    return _SEEN[key]


_SEEN: dict[tuple, int] = {}  # _screen_pixels' last answers


def atlas_padding(scene: Scene, params: Mapping[str, Any],
                  artifacts: Mapping[str, Any] | None) -> str | None:
    """The objects whose atlas is mostly padding (covered fraction below
    :data:`LEAST_COVERED_FRACTION`)."""
    if artifacts is None:
        return None
    attrs = artifacts["triple.atlas"].attrs
    found = []
    for obj, counts in attrs["texel_counts"].items():
        height, width = attrs["texture_sizes"][obj]
        covered = counts["covered"] / (height * width)
        if covered < LEAST_COVERED_FRACTION:
            found.append(f"objects.{obj}: {100 * covered:.0f} % of its {height}×{width} "
                         "atlas is covered, the rest padding between small charts "
                         "(surface detail is lost and the object darkens): raise "
                         f"triple.texels_per_pixel ({attrs['texels_per_pixel']:g}) or "
                         "simplify the mesh")
    return "; ".join(found) or None
