"""Shared set-up of the sg fit benchmarks: ``scenes/bunny_sg.yaml`` (the coarse bunny,
Blinn–Phong γ 60, ρs 0.1, welded; a diffuse ground; Grace) baked up to ``sg.diffuse``
in a work directory, and the stage's own transport function (direct + indirect glossy,
pipeline/methods/sg/stages/fit.py ``chunk_transport``) over a connected patch of bunny vertices.

Not a benchmark itself: ``sg_fit_flips.py`` and ``sg_fit_stage.py`` import it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from pipeline import job  # noqa: E402
from pipeline.engine.planning import resolve_sections, stage_params  # noqa: E402
from pipeline.engine.stage import ChunkContext  # noqa: E402
from pipeline.engine.store import Workdir, open_artifact  # noqa: E402
from pipeline.methods.sg.stages import fit as stage  # noqa: E402

SCENE = ROOT / "scenes" / "bunny_sg.yaml"


@dataclass
class BunnyPatch:
    """A connected patch of the bunny's vertices, as the stage's flood fill sees a batch."""

    transport: Callable[[np.ndarray], np.ndarray]  # local indices (G,) -> T (G, 92, S, 3)
    normals: np.ndarray      # (P, 3) unit
    edges: np.ndarray        # (E, 2) local indices
    vertices: np.ndarray     # (P,) global vertex indices
    brdf: object             # the bunny's glossy BrdfParams
    directions: np.ndarray   # (S, 3) the fit grid
    omega: np.ndarray        # (S,) its solid angles
    params: dict             # the stage's params (stages.yaml defaults)
    bunny_vertices: int      # vertices of the whole bunny object


def breadth_first(count: int, neighbours: list[np.ndarray], root: int) -> np.ndarray:
    """The first ``count`` vertices of a breadth-first walk from ``root``."""
    seen, queue, out = {root}, [root], []
    while queue and len(out) < count:
        v = queue.pop(0)
        out.append(v)
        for u in neighbours[v]:
            if int(u) not in seen:
                seen.add(int(u))
                queue.append(int(u))
    return np.asarray(out, np.int64)


def bunny_patch(workdir: Path, count: int, settings: dict | None = None,
                seed: int = 0, scene_file: Path = SCENE, obj_name: str = "bunny",
                root: int = 0
                ) -> BunnyPatch:
    """Bake ``geometry`` and ``sg.diffuse`` of bunny_sg (or ``scene_file``) into
    ``workdir`` (once; later calls find them fresh) and return ``count`` vertices of
    object ``obj_name`` from a breadth-first walk from its vertex ``root``, with the stage's
    transport function on the fit grid and its params: stages.yaml's defaults updated by
    ``settings``."""
    scene = job.open_scene(scene_file)
    wd = Workdir(workdir)
    job.bake(scene, wd, until="sg.diffuse", quiet=True)
    graph = job.stages()
    params = {**stage_params(graph, scene), **(settings or {})}
    spec = graph.stages["sg.fit"]
    inputs = {name: open_artifact(wd.artifact(name), graph.stages[name].output)
              for name in spec.inputs}
    ctx = ChunkContext(params=params, scene=resolve_sections(spec, scene, None),
                       inputs=inputs, rng=np.random.default_rng(seed))
    geometry = inputs["geometry"]
    obj = geometry.attrs["object_names"].index(obj_name)
    material = geometry.attrs["material_names"][int(geometry.read("object_material")[obj])]
    first, end = (int(x) for x in geometry.read("object_ranges")[obj, :2])
    faces = geometry.read("faces")
    _, neighbours = stage.flood_order(end - first, stage.batch_edges(faces, first, end))
    local = breadth_first(count, neighbours, root)
    vertices = first + local
    position = np.full(end - first, -1)
    position[local] = np.arange(len(local))
    e = position[stage.batch_edges(faces, first, end)]
    edges = e[(e >= 0).all(axis=1)]
    directions, omega = stage.grid(params)
    whole = stage.chunk_transport(ctx, first, directions)
    normals = geometry.read("normals")[vertices].astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return BunnyPatch(lambda g: whole(local[g]), normals, np.sort(edges, axis=1), vertices,
                      stage.material_brdf(ctx, material), directions, omega, params,
                      end - first)
