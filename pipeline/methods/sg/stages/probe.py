"""Stage ``sg.probe``: the tabulated glossy transport of the vertices a user asks to
inspect (method sg, paper 003 §3; issue 17: the transport of every vertex does not fit
on disk — 92 views × ``sg.fit_grid`` directions × RGB each — so ``sg.fit`` computes it
inside its chunks and keeps only the Gaussians). Schema ``sg_probe``; one chunk.

For each vertex of ``sg.probe_vertices`` (global vertex indices of the ``geometry``
artifact) it stores exactly what ``sg.fit`` fits: T (92 views, S directions, 3) in 1/sr
from pipeline/methods/sg/transport.py ``glossy_transport`` — direct glossy (BRDF ×
visibility × cos) plus indirect glossy through the ``sg.diffuse`` transfer with
``sg.indirect_samples`` paths per view — on the lat-long grid ``sg.fit_grid``, with its
directions and solid angles, so that glossy radiance towards view k is
Σ_s T[p, k, s] L(ω_s) Ω_s. The indirect part is a Monte Carlo estimate seeded from the
chunk's key: another stage's draw (sg.fit's) differs by its noise.

Not part of method sg's frames (the method does not read it): bake it on demand,
``prt run SCENE --until sg.probe`` with ``settings: {sg.probe_vertices: [i, j, ...]}``
in the scene file.
"""

from __future__ import annotations

import numpy as np

from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.methods.sg.stages.fit import grid, transport_scene
from pipeline.methods.sg.transport import glossy_transport, view_directions

MAX_PROBES = 64  # 92 × 6,050 × 3 float32 = 6.7 MB per vertex at the default grid


def probe_vertices(params: dict, vertex_count: int) -> np.ndarray:
    """``sg.probe_vertices`` as global vertex indices (P,) int64; PrtError naming the
    param where the list is empty, too long, or holds an index outside the geometry."""
    given = params["sg.probe_vertices"]
    vertices = np.asarray(given if given is not None else [], np.int64).reshape(-1)
    if len(vertices) == 0:
        raise PrtError("sg.probe_vertices", "empty: list the vertex indices to tabulate "
                       "(scene file: settings: {sg.probe_vertices: [i, j, ...]})")
    if len(vertices) > MAX_PROBES:
        raise PrtError("sg.probe_vertices", f"{len(vertices)} vertices: at most "
                       f"{MAX_PROBES} (each stores 92 views × the fit grid × RGB)")
    bad = vertices[(vertices < 0) | (vertices >= vertex_count)]
    if len(bad):
        raise PrtError("sg.probe_vertices", f"vertex {int(bad[0])} is not one of the "
                       f"geometry's {vertex_count} vertices")
    return vertices


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    """T of every probe vertex, (P, 92, S, 3) float32, and the grid."""
    geometry = ctx.inputs["geometry"]
    normals = geometry.read("normals").astype(np.float64)
    vertices = probe_vertices(ctx.params, len(normals))
    directions, omega = grid(ctx.params)
    values = glossy_transport(transport_scene(ctx), vertices, directions,
                              ctx.inputs["sg.diffuse"].read("transfer"),
                              int(ctx.params["sg.indirect_samples"]), ctx.rng)
    normal = normals[vertices] / np.linalg.norm(normals[vertices], axis=1, keepdims=True)
    return {"values": values, "directions": directions, "solid_angles": omega,
            "vertex": vertices, "normal": normal, "views": view_directions()}


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"probe_chunk": 1})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    rows, cols = (int(n) for n in ctx.params["sg.fit_grid"])
    return Output({"grid": {"kind": "latlong", "rows": rows, "columns": cols,
                            "directions": rows * cols},
                   "indirect_samples": int(ctx.params["sg.indirect_samples"]),
                   "transport": "direct glossy (BRDF x visibility x cos) + indirect glossy "
                                "(glossy-to-diffuse paths through the sg.diffuse transfer), "
                                "as sg.fit fits it"})
