"""Stage implementations and the contract between a stage and the runner.

A stage module provides two plain functions:

``run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]``
    computes one chunk (an object, a pixel tile, or the whole stage) from its declared
    inputs, params and scene sections; it opens no files and picks no paths.
``assemble(ctx: AssembleContext, pieces: list[tuple[Chunk, dict]]) -> Output``
    combines the chunks' results (in chunk order) into the artifact's arrays and attrs.

The runner owns everything else: keys, I/O, seeding, progress and executors.

stages.yaml names a stage's implementation by module: ``impl: transfer`` is the module
``pipeline.stages.transfer``; a dotted name (``toy.per_object``, ``pkg.mod:attr``) is
imported as it is (a plug-in's own stages).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.chunk import ALL, Chunk
from pipeline.meshio import RawMesh
from pipeline.store import Artifact

__all__ = ["AssembleContext", "Chunk", "ChunkContext", "Output", "stitch_tiles"]


@dataclass
class AssembleContext:
    """What a stage sees when assembling: its params, scene sections and inputs."""

    params: dict[str, Any]
    scene: dict[str, Any]
    inputs: dict[str, Artifact]


@dataclass
class ChunkContext(AssembleContext):
    """What a stage sees for one chunk; ``rng`` is seeded from the data part of the
    chunk's key (params, scene sections, input digests, chunk id; not the code), and
    ``meshes`` holds raw meshes of the objects whose ``mesh`` section it declares."""

    chunk: Chunk = ALL
    key: str = ""
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    meshes: dict[str, RawMesh] = field(default_factory=dict)


@dataclass
class Output:
    """An artifact's content: arrays and attrs as its schema declares, plus the sizes
    that resolve symbolic chunk entries (e.g. ``{"tile": 64}``)."""

    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any]
    sizes: dict[str, int] = field(default_factory=dict)


def stitch_tiles(pieces: list[tuple[Chunk, dict[str, np.ndarray]]], height: int,
                 width: int) -> dict[str, np.ndarray]:
    """Place tile chunks' (th, tw, ...) arrays into full (height, width, ...) images."""
    first = pieces[0][1]
    images = {name: np.zeros((height, width, *a.shape[2:]), dtype=a.dtype)
              for name, a in first.items()}
    for chunk, arrays in pieces:
        y0, y1, x0, x1 = chunk.region
        for name, a in arrays.items():
            images[name][y0:y1, x0:x1] = a
    return images
