"""Stage ``sg.env_prefilter``: the scene's environment map convolved with normalised
spherical Gaussians of increasing σ, one lat-long level per σ (method sg, paper 003 §5);
and the map split into its bright sources and a residual, prefiltered the same way
(pipeline/methods/sg/sources.py, decision 0048: what ``normal=visibility`` reads).
Schema ``sg_prefilter``; one chunk (the whole stack).

The σ ladder is sg.prefilter_levels (σ_0 one row of the map, ratio ``sg.prefilter_ratio``
up to ``sg.prefilter_sigma_max``), each level computed by pipeline/methods/sg/prefilter.py
(row pairs in the Fourier domain along φ; equal to the brute-force
sg.prefilter_reference up to rounding). The map's rotation and scale are applied by the
renderer: the key holds the map file's bytes (scene section ``environment.file``) and
the params only, so editing the map re-runs this stage and nothing else of the scene
does.

One chunk rather than one per level: the level count follows from the map's height,
which a chunker could know only by reading the map, and the whole stack of a 1024 × 512
map takes seconds (studies/sg_prefilter_speed.py).
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.math.sg import PrefilterLevels, pack_stack, prefilter_levels
from pipeline.methods.sg.prefilter import prefilter
from pipeline.methods.sg.sources import split_sources

TEXEL_CHUNK = 1 << 16  # stored texels per zarr chunk


def levels_of(shape: tuple[int, int], params: dict) -> PrefilterLevels:
    """The σ ladder of a map of ``shape`` (H, W) under the stage's params."""
    ratio, sigma_max = float(params["sg.prefilter_ratio"]), float(params["sg.prefilter_sigma_max"])
    if not ratio > 1.0:
        raise PrtError("sg.prefilter_ratio", f"{ratio}: the σ ratio between levels must be > 1")
    if not sigma_max > 0.0:
        raise PrtError("sg.prefilter_sigma_max", f"{sigma_max}: must be > 0 radians")
    return prefilter_levels(shape[0], shape[1], ratio, sigma_max)


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """The whole stack: packed texels, (first, W, H) per level and σ per level; the
    residual's stack in the same layout and the sources."""
    if ctx.environment is None:
        raise PrtError(None, "method sg needs an environment light (lights: "
                       "[{type: environment, file: ...}])")
    levels = levels_of(ctx.environment.shape[:2], ctx.params)
    texels, info = pack_stack(prefilter(ctx.environment, levels))
    sources, residual = split_sources(ctx.environment, float(ctx.params["sg.source_quantile"]),
                                      float(ctx.params["sg.source_min_share"]))
    residual_texels = texels if not len(sources) else \
        pack_stack(prefilter(residual, levels))[0]
    ctx.meta.update(map_shape=list(ctx.environment.shape[:2]), sigma0=levels.sigma0,
                    levels=levels.count, sources=len(sources))
    return {"texels": texels.reshape(-1, 3), "level": info, "sigma": levels.sigmas,
            "residual": residual_texels.reshape(-1, 3),
            "sources": sources.astype(np.float32).reshape(-1, 7)}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"texel_chunk": TEXEL_CHUNK})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    meta = metas[0][1]
    return Output({"sigma0": float(meta["sigma0"]),
                   "ratio": float(ctx.params["sg.prefilter_ratio"]),
                   "sigma_max": float(ctx.params["sg.prefilter_sigma_max"]),
                   "levels": int(meta["levels"]), "map_shape": meta["map_shape"],
                   "sources": int(meta["sources"]),
                   "source_quantile": float(ctx.params["sg.source_quantile"]),
                   "source_min_share": float(ctx.params["sg.source_min_share"])})


def read_stack(artifact: Artifact, name: str = "texels"
               ) -> tuple[list[np.ndarray], PrefilterLevels]:
    """The levels (H_ℓ, W_ℓ, 3) float32 and their ladder from the opened artifact:
    the map's (``name`` ``texels``) or the residual's (``residual``)."""
    texels, info = artifact.read(name), artifact.read("level")
    stack = [texels[first:first + w * h].reshape(h, w, 3) for first, w, h in info]
    attrs = artifact.attrs
    return stack, PrefilterLevels(float(attrs["sigma0"]), float(attrs["ratio"]),
                                  tuple((int(h), int(w)) for _, w, h in info))
