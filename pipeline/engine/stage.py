"""Stage implementations and the contract between a stage and the runner.

A stage module provides plain functions:

``layout(ctx: AssembleContext) -> Layout`` (optional)
    before any chunk runs: the full shapes of the artifact's ``region`` arrays and the
    symbolic zarr chunk sizes of its schema (``tile``, ``row_chunk``, ...);
``run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray | Block]``
    computes one chunk (an object, a pixel tile, a block, or the whole stage) from its
    declared inputs, params and scene sections: a :class:`Block` of each ``region``
    array, its piece of each ``segments`` array, the ``whole`` arrays of an unchunked
    stage (pipeline/engine/schema.py); small per-chunk facts for ``finalize`` go in
    ``ctx.meta`` (JSON values). It opens no files and picks no paths;
``finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output``
    once every chunk is written: the artifact's attributes, any small ``whole``
    arrays derived from the chunks' metadata (in chunk order), and the results of the
    budgets it chose from a tolerance (pipeline/engine/tolerance.py), which the runner records
    and reports.

The runner owns everything else: keys, I/O (chunks are written in place into the final
artifact, pipeline/engine/chunkwrite.py), seeding, progress and executors.

stages.yaml names a stage's implementation by module: ``impl: gbuffer`` is the module
``pipeline.stages.gbuffer`` (the stages every method may read); a dotted name
(``pipeline.methods.d2i.stages.transfer``, ``toy.per_object``, ``pkg.mod:attr``) is
imported as it is (a method's own stages).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.engine.chunk import ALL, Chunk
from pipeline.engine.chunkwrite import Block
from pipeline.engine.store import Artifact
from pipeline.engine.tolerance import ToleranceResult
from pipeline.scene.meshio import RawMesh

__all__ = ["AssembleContext", "Block", "Chunk", "ChunkContext", "Layout", "Output",
           "ToleranceResult", "tile_blocks"]


@dataclass
class AssembleContext:
    """What a stage sees when assembling: its params, scene sections and inputs."""

    params: dict[str, Any]
    scene: dict[str, Any]
    inputs: dict[str, Artifact]


@dataclass
class ChunkContext(AssembleContext):
    """What a stage sees for one chunk; ``rng`` is seeded from the data part of the
    chunk's key (params, scene sections, input digests, chunk id; not the code),
    ``meshes`` holds raw meshes of the objects whose ``mesh`` section it declares, and
    ``environment`` the scene's environment map, (height, width, 3) float32 radiance as
    ``pipeline.images.read_environment`` checked it, when the stage declares the
    ``environment.file`` section (None otherwise, or without an environment light)."""

    chunk: Chunk = ALL
    key: str = ""
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    meshes: dict[str, RawMesh] = field(default_factory=dict)
    environment: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class Layout:
    """What a chunked artifact looks like before its chunks run: ``shapes`` of its
    ``region`` arrays, ``sizes`` resolving symbolic chunk entries (``{"tile": 64}``)."""

    shapes: dict[str, tuple[int, ...]] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)


@dataclass
class Output:
    """What ``finalize`` adds: the artifact's ``attrs``, small ``whole`` arrays, and one
    :class:`ToleranceResult` per budget the stage chose from a tolerance."""

    attrs: dict[str, Any]
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    tolerances: list[ToleranceResult] = field(default_factory=list)


def tile_blocks(chunk: Chunk, arrays: dict[str, np.ndarray]) -> dict[str, Block]:
    """A pixel (or texel) tile chunk's (th, tw, ...) arrays as blocks of full images."""
    y0, _, x0, _ = chunk.region
    return {name: Block((y0, x0), a) for name, a in arrays.items()}
