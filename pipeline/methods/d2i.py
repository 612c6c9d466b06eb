"""Method ``d2i``: direct-to-indirect transfer with PCA-linearized BRDF editing (paper 000).

Stages (stages.yaml, ``d2i.*``): ``d2i.gather`` (gather samples by backward photon
shooting), ``d2i.transfer`` (per-pixel T and D rows over the gather disks, Haar
compressed, pixel tiles), ``d2i.bounce`` (Ms between gather samples, blocks),
``d2i.truncate`` (rows cut to the renderer's budgets); shared: ``geometry``,
``gbuffer``, ``brdf_basis``. Renderer: pipeline/render/d2i.py.

Run-time options (``prt render --option NAME=VALUE``):

* ``max_bounces`` (int, 32): diffuse bounces between gather samples at most;
* ``bounce_tolerance`` (float, 1e-3): stop bouncing when a bounce adds less than this
  fraction (relative L2) of the gather radiance.

Sequences (``--frames``): ``light:N`` moves the first light around a horizontal circle
of radius 0.1 × the scene's diagonal (light-edit mode, rows frozen); ``gamma[:M]:N``
sweeps material M's γ (default: the first glossy one) geometrically over its
``gamma_range`` (BRDF-edit mode).

Scene requirements: every glossy material has a ``gamma_range`` (the range its PCA basis
covers, γ edits stay inside it); its ``pca_tolerance`` is optional.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.method import Component, Method, Option
from pipeline.scene import Scene
from pipeline.scene_edits import with_light_offset, with_material_edits
from pipeline.store import Artifact

METHOD = Method(
    name="d2i",
    description="paper 000: direct-to-indirect transfer, PCA-linearized BRDF editing",
    renderer="pipeline.render.d2i:d2i_renderer",
    reads=("geometry", "gbuffer", "brdf_basis", "d2i.gather", "d2i.truncate"),
    reference="first-glossy",
    headline="rel_rmse_surfaces",
    components={"indirect": Component(subtract="direct", transport="first-glossy-indirect")},
    options=(
        Option("max_bounces", int, 32, "diffuse bounces between gather samples at most"),
        Option("bounce_tolerance", float, 1e-3,
               "stop bouncing when a bounce adds less than this fraction (L2)"),
    ),
    sequences="pipeline.methods.d2i:sequence",
    main_sequences=("light:8", "gamma:8"),
    evaluate_sweep={"gather.count": [4096, 16384]},
    evaluate_size=96,
    evaluate_reference_spp=1024,
    lights=("point", "spot", "directional", "quad"),
    features=("emitters",),
    check_scene="pipeline.methods.d2i:check_scene",
)

SEQUENCE_KINDS = ("light", "gamma")


def check_scene(scene: Scene) -> None:
    """Every glossy material needs the γ range its PCA basis is baked over."""
    for name, material in scene.materials.items():
        if material.model != "lambert" and "gamma_range" not in material.params:
            raise PrtError(scene.path, f"materials.{name}.gamma_range: method d2i needs the "
                           "range of gamma its PCA basis covers, e.g. [3, 300]")


def parse_sequence(text: str) -> tuple[str, str | None, int]:
    """``light:N`` or ``gamma[:MATERIAL]:N`` -> (kind, material or None, N)."""
    parts = text.split(":")
    if parts[0] not in SEQUENCE_KINDS or len(parts) not in (2, 3) or \
            (parts[0] == "light" and len(parts) != 2) or not parts[-1].isdigit() \
            or int(parts[-1]) < 1:
        raise PrtError(None, f"--frames {text}: expected light:N or gamma[:MATERIAL]:N "
                       "(N ≥ 1 frames)")
    return parts[0], parts[1] if len(parts) == 3 else None, int(parts[-1])


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str
             ) -> tuple[str, list[Scene], list[str]]:
    """The edit kind, edited scenes and a label for each frame of ``spec``."""
    kind, material, count = parse_sequence(spec)
    if kind == "light":
        if not scene.lights:
            raise PrtError(scene.path, "a light sequence needs a light to move")
        geo = artifacts["geometry"].attrs
        radius = 0.1 * float(np.linalg.norm(np.subtract(geo["bbox_max"], geo["bbox_min"])))
        angles = 2 * np.pi * np.arange(count) / count
        offsets = [(radius * np.cos(a), 0.0, radius * np.sin(a)) for a in angles]
        return (kind, [with_light_offset(scene, 0, o) for o in offsets],
                [f"light 0 moved by ({o[0]:.3g}, {o[1]:.3g}, {o[2]:.3g})" for o in offsets])
    glossy = [n for n, m in scene.materials.items() if m.model != "lambert"]
    name = material or (glossy[0] if glossy else None)
    if name not in glossy:
        raise PrtError(scene.path, f"a gamma sequence needs a glossy material (found "
                       f"{name!r}; glossy: {', '.join(glossy) or 'none'})")
    params: dict[str, Any] = scene.materials[name].params
    lo, hi = params["gamma_range"]
    gammas = np.geomspace(lo, hi, count) if count > 1 else [params["gamma"]]
    edits = [f"{name}.gamma={g:.6g}" for g in gammas]
    return kind, [with_material_edits(scene, [e]) for e in edits], edits
