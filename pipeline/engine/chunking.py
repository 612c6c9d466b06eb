"""Chunks and chunkers: how a stage's work is cut into independent units.

A :class:`Chunk` is (id, kind, coordinates). A chunker is a function of (stage spec,
scene, params, upstream artifacts) returning the stage's chunks in a stable order; it may
read the upstream artifacts' attributes (and, for ``materials_from``, one small array),
so chunkings that exist only after an upstream stage ran (texel tiles of a UV atlas,
vertex batches of a mesh) are planned from data. The runner plans a stage's chunks when
its inputs are fresh, just before it runs.

Chunkings (``chunks:`` in stages.yaml):

=============== ====================================== ==================================
by              chunks                                 coordinates
=============== ====================================== ==================================
none            one, id ``all``                        –
object          one per scene object                   ``object``, ``index`` (scene order)
material        one per scene material                 ``material``, ``index``
tile            pixel tiles of ``size`` (a param)      ``region`` (y0, y1, x0, x1) px;
                                                       ``materials`` seen in it if
                                                       ``materials_from`` names a stage
                                                       with a ``material_id`` image
tile_material   per pixel tile of ``size``, one per    ``region``, ``materials`` (the
                material seen in it (from              one), ``tile`` (the id of the
                ``materials_from``) whose model is     tile chunk it splits)
                not in ``skip_models``; id
                ``TILE/MATERIAL``
block           [0, ``of``) in blocks of ``size``      ``span`` (start, end)
                (``of``: a count, or a grid's shape
                whose product is the count)
texel_tile      per object, tiles of its texture      ``object``, ``region`` in texels
                (``of``'s attr ``texture_sizes``:
                {object: [height, width]})
vertex_batch    per object, the fewest runs of at      ``object``, ``span`` (start, end)
                most ``size`` vertices, of even        in the object's own vertices
                lengths (``of``'s attr
                ``vertex_counts``: {object: count})
=============== ====================================== ==================================
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Mapping
from functools import reduce
from typing import Any

import numpy as np

from pipeline.engine.chunk import ALL, Chunk, make_chunk
from pipeline.engine.stagefile import StageSpec
from pipeline.errors import PrtError
from pipeline.scene.model import Scene


def _positive(scene: Scene, name: str, value: Any) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise PrtError(scene.path, f"{name}: expected a positive integer, found {value!r}")
    return value


def _tiles(height: int, width: int, tile: int) -> list[tuple[int, int, int, int]]:
    return [(y, min(y + tile, height), x, min(x + tile, width))
            for y in range(0, height, tile) for x in range(0, width, tile)]


def _tiles_seen(spec: StageSpec, scene: Scene, params: dict[str, Any],
                upstream: Mapping[str, Any]
                ) -> list[tuple[str, tuple[int, int, int, int], tuple[str, ...] | None]]:
    """(id, region, materials seen or None without ``materials_from``) per pixel tile."""
    tile = _positive(scene, spec.chunks.size, params[spec.chunks.size])
    regions = _tiles(scene.camera.height, scene.camera.width, tile)
    ids = [f"y{y0:05d}_x{x0:05d}" for y0, _, x0, _ in regions]
    if spec.chunks.materials_from is None:
        return [(i, r, None) for i, r in zip(ids, regions, strict=True)]
    material_id = upstream[spec.chunks.materials_from].read("material_id")
    names = list(scene.materials)
    return [(i, (y0, y1, x0, x1),
             tuple(names[m] for m in np.unique(material_id[y0:y1, x0:x1]) if m >= 0))
            for i, (y0, y1, x0, x1) in zip(ids, regions, strict=True)]


def _pixel_tiles(spec: StageSpec, scene: Scene, params: dict[str, Any],
                 upstream: Mapping[str, Any]) -> list[Chunk]:
    return [make_chunk(i, "tile", region=r) if seen is None else
            make_chunk(i, "tile", region=r, materials=seen)
            for i, r, seen in _tiles_seen(spec, scene, params, upstream)]


def _tile_materials(spec: StageSpec, scene: Scene, params: dict[str, Any],
                    upstream: Mapping[str, Any]) -> list[Chunk]:
    skip = set(spec.chunks.skip_models)
    return [make_chunk(f"{i}/{m}", "tile_material", region=r, materials=(m,), tile=i)
            for i, r, seen in _tiles_seen(spec, scene, params, upstream)
            for m in seen or () if scene.materials[m].model not in skip]


def _blocks(spec: StageSpec, scene: Scene, params: dict[str, Any],
            upstream: Mapping[str, Any]) -> list[Chunk]:
    size = _positive(scene, spec.chunks.size, params[spec.chunks.size])
    of = params[spec.chunks.count]
    if isinstance(of, list):  # a grid's shape: its entries in index order
        of = reduce(operator.mul, (_positive(scene, spec.chunks.count, n) for n in of), 1)
    count = _positive(scene, spec.chunks.count, of)
    return [make_chunk(f"b{s:08d}", "block", span=(s, min(s + size, count)))
            for s in range(0, count, size)]


def _upstream_attr(spec: StageSpec, upstream: Mapping[str, Any], attr: str) -> dict:
    value = upstream[spec.chunks.of].attrs.get(attr)
    if not isinstance(value, dict):
        raise PrtError(upstream[spec.chunks.of].path, f"attribute {attr!r} (a mapping from "
                       f"object to size) missing; stage {spec.name} is chunked by it")
    return value


def _texel_tiles(spec: StageSpec, scene: Scene, params: dict[str, Any],
                 upstream: Mapping[str, Any]) -> list[Chunk]:
    tile = _positive(scene, spec.chunks.size, params[spec.chunks.size])
    chunks = []
    for obj, (height, width) in _upstream_attr(spec, upstream, "texture_sizes").items():
        chunks.extend(make_chunk(f"{obj}/y{y0:05d}_x{x0:05d}", "texel_tile", object=obj,
                                 region=(y0, y1, x0, x1))
                      for y0, y1, x0, x1 in _tiles(int(height), int(width), tile))
    return chunks


def _vertex_batches(spec: StageSpec, scene: Scene, params: dict[str, Any],
                    upstream: Mapping[str, Any]) -> list[Chunk]:
    size = _positive(scene, spec.chunks.size, params[spec.chunks.size])
    chunks = []
    for obj, count in _upstream_attr(spec, upstream, "vertex_counts").items():
        bounds = even_runs(int(count), size)
        chunks.extend(make_chunk(f"{obj}/v{s:08d}", "vertex_batch", object=obj, span=(s, e))
                      for s, e in zip(bounds[:-1], bounds[1:], strict=True))
    return chunks


def even_runs(count: int, size: int) -> list[int]:
    """Bounds of the fewest runs of at most ``size`` items covering [0, ``count``),
    their lengths differing by at most one: 453 in runs of at most 256 -> [0, 226, 453].
    Even, so that no run is a short remainder: workers sharing an object's runs finish
    together (runs of 256 and 197 left one of two workers idle for the last tenth)."""
    runs = -(-count // size)
    return [count * i // runs for i in range(runs + 1)] if runs else [0]


Chunker = Callable[[StageSpec, Scene, dict[str, Any], Mapping[str, Any]], list[Chunk]]

CHUNKERS: dict[str, Chunker] = {
    "none": lambda spec, scene, params, upstream: [ALL],
    "object": lambda spec, scene, params, upstream: [
        make_chunk(name, "object", object=name, index=i)
        for i, name in enumerate(scene.objects)],
    "material": lambda spec, scene, params, upstream: [
        make_chunk(name, "material", material=name, index=i)
        for i, name in enumerate(scene.materials)],
    "tile": _pixel_tiles,
    "tile_material": _tile_materials,
    "block": _blocks,
    "texel_tile": _texel_tiles,
    "vertex_batch": _vertex_batches,
}


def plan_chunks(spec: StageSpec, scene: Scene, params: dict[str, Any],
                upstream: Mapping[str, Any]) -> list[Chunk]:
    """The chunks of ``spec`` (``upstream``: its input artifacts, opened, by stage)."""
    return CHUNKERS[spec.chunks.by](spec, scene, params, upstream)
