"""Shared test helpers: small scenes written on the fly, and the shared data folder."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

PROJECT = Path(__file__).resolve().parent.parent
TESTS = Path(__file__).resolve().parent
# The shared data folder: $PRT_DATA, else ../shared/data beside the checkout (as in CI).
SHARED_DATA = Path(os.environ.get("PRT_DATA") or PROJECT.parent / "shared" / "data")


def small_scene_dict(size: int = 24) -> dict[str, Any]:
    """A tiny scene: a floor plane, a box and a sphere; a point light and a quad light."""
    return {
        "format": "prt-scene/1",
        "name": "tiny",
        "camera": {"position": [0.0, 1.5, 4.0], "look_at": [0.0, 0.3, 0.0], "up": [0, 1, 0],
                   "fov": 45, "width": size, "height": size},
        "materials": {
            "grey": {"model": "lambert", "albedo": [0.6, 0.6, 0.6]},
            "red": {"model": "lambert", "albedo": [0.7, 0.1, 0.1]},
            "shiny": {"model": "blinn_phong", "albedo": [0.2, 0.4, 0.6], "specular": 0.1,
                      "gamma": 20, "gamma_range": [3, 300]},
        },
        "objects": {
            "floor": {"primitive": {"type": "plane", "size": [4, 4]}, "material": "grey"},
            "box": {"primitive": {"type": "box", "size": [0.6, 0.6, 0.6]},
                    "transform": {"translate": [-0.6, 0.3, 0.0], "rotate": [0, 30, 0]},
                    "material": "red"},
            "ball": {"primitive": {"type": "sphere", "radius": 0.35, "subdivisions": 2},
                     "transform": {"translate": [0.6, 0.35, 0.2]}, "material": "shiny"},
        },
        "lights": [
            {"type": "point", "position": [1.0, 2.0, 1.0], "intensity": [3.0, 3.0, 3.0]},
            {"type": "quad", "corner": [-0.5, 2.5, -0.5], "edge_u": [1.0, 0, 0],
             "edge_v": [0, 0, 1.0], "radiance": [2.0, 2.0, 2.0], "samples": 4},
        ],
    }


# every stage of method d2i's bake and their shared upstream, in run order
D2I_STAGES = ("geometry", "brdf_basis", "gbuffer", "d2i.gather", "d2i.transfer",
              "d2i.transfer_t", "d2i.bounce", "d2i.truncate", "d2i.truncate_t",
              "d2i.truncate_ms")

TOY_STAGEFILE = TESTS / "toy" / "stages.yaml"
TOY_STAGES = ("geometry", "gbuffer", "per_object", "total", "tiles")


def artifact_bytes(workdir: Any, stages: tuple[str, ...] = TOY_STAGES
                   ) -> dict[str, dict[str, bytes]]:
    """Every array of every stage's artifact in ``workdir`` (a Workdir), as raw bytes."""
    from pipeline.engine.store import open_artifact

    return {s: {n: a.tobytes() for n, a in open_artifact(workdir.artifact(s)).read_all().items()}
            for s in stages}


def write_scene(folder: Path, doc: dict[str, Any], name: str = "scene.yaml") -> Path:
    """Write a scene dictionary as YAML into ``folder``; returns its path."""
    path = folder / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def scene_geometry(folder: Path, doc: dict[str, Any]) -> tuple[Any, dict]:
    """Write ``doc`` into ``folder``, bake its geometry there; (scene, geometry arrays)."""
    from pipeline import job
    from pipeline.scene.file import load_scene

    scene = load_scene(write_scene(folder, doc))
    geometry, _ = job.load_geometry(scene, job.workdir_for(scene, folder / "work"))
    return scene, geometry


def constant_environment(path: Path, radiance: list[float]) -> Path:
    """A small latitude-longitude EXR of constant ``radiance`` (RGB)."""
    import numpy as np

    from pipeline.images import write_exr

    write_exr(path, np.broadcast_to(np.asarray(radiance, np.float32), (8, 16, 3)))
    return path
