"""Method ``d2i``: direct-to-indirect transfer with PCA-linearized BRDF editing (paper 000).

Stages (this folder's stages.yaml, ``d2i.*``): ``d2i.gather`` (gather samples by backward photon
shooting), ``d2i.transfer`` (per-pixel D rows over the gather disks, Haar compressed,
and the glossy pixels' visibility; pixel tiles), ``d2i.transfer_t`` (T rows from that
visibility; a tile's pixels of one glossy material), ``d2i.bounce`` (Ms between gather
samples, blocks), ``d2i.truncate`` (D rows cut to the renderer's budget, pixel tiles),
``d2i.truncate_t`` (T rows cut, as d2i.transfer_t), ``d2i.truncate_ms`` (Ms rows cut,
blocks); shared: ``geometry``, ``gbuffer``, ``brdf_basis``. Renderer:
pipeline/methods/d2i/render.py.

Run-time options (``prt render --option NAME=VALUE``):

* ``max_bounces`` (int, 32): diffuse bounces between gather samples at most;
* ``bounce_tolerance`` (float, 1e-3): stop bouncing when a bounce adds less than this
  fraction (relative L2) of the gather radiance;
* ``shadows`` (``auto``): the frames' shadow rays — ``device`` (a BVH kernel on the
  OpenCL device), ``embree`` (on the host), ``auto`` (the device's on a GPU);
* ``layout`` (``auto``): the products' layout — ``gpu`` (float16 values, a work-group
  per row), ``cpu`` (float32 values, a work-item per row), ``auto`` (by the device).
  Both choices change speed only (the same frames to float16 rounding).

Sequences (``--frames``): ``light[:LIGHT]:N`` moves light LIGHT (an index into
``lights`` or a quad light's ``object``; default the first point, spot or quad light)
around a horizontal circle of radius 0.1 × the scene's diagonal centred on it (light-edit
mode, rows frozen; its emitter object moves with it, pipeline/render/emitters.py);
``gamma[:M]:N`` sweeps material M's γ (default: the first glossy one) geometrically over
its ``gamma_range`` (BRDF-edit mode). ``prt run`` skips a sequence the scene has nothing
for (no light with a position, no glossy material), saying so.

Scene requirements: every glossy material has a ``gamma_range`` (the range its PCA basis
covers, γ edits stay inside it); its ``pca_tolerance`` is optional.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pipeline.errors import PrtError
from pipeline.method import Component, Method, NotApplicable, Option
from pipeline.render import sequences
from pipeline.render.sequences import Sequence
from pipeline.scene import Scene
from pipeline.scene_edits import with_light_offset
from pipeline.store import Artifact

METHOD = Method(
    name="d2i",
    stagefile=Path(__file__).with_name("stages.yaml"),
    description="paper 000: direct-to-indirect transfer, PCA-linearized BRDF editing",
    renderer="pipeline.methods.d2i.render:d2i_renderer",
    reads=("geometry", "gbuffer", "brdf_basis", "d2i.gather", "d2i.truncate",
           "d2i.truncate_t", "d2i.truncate_ms"),
    reference="first-glossy",
    headline="rel_rmse_surfaces",
    components={"indirect": Component(subtract="direct", transport="first-glossy-indirect")},
    options=(
        Option("max_bounces", int, 32, "diffuse bounces between gather samples at most",
               least=0),
        Option("bounce_tolerance", float, 1e-3,
               "stop bouncing when a bounce adds less than this fraction (L2)", least=0),
        Option("shadows", str, "auto",
               "shadow rays: device (BVH kernel), embree (host) or auto (device on a GPU)",
               choices=("device", "embree", "auto")),
        Option("layout", str, "auto",
               "products: gpu (float16, a work-group per row), cpu or auto (by device)",
               choices=("gpu", "cpu", "auto")),
    ),
    sequences="pipeline.methods.d2i:sequence",
    sequence_forms=("light[:LIGHT]:N", "gamma[:MATERIAL]:N"),
    main_sequences=("light:8", "gamma:8"),
    evaluate_sweep={"gather.count": [4096, 16384]},
    evaluate_size=96,
    evaluate_reference_spp=1024,
    lights=("point", "spot", "directional", "quad"),
    features=("emitters",),
    check_scene="pipeline.methods.d2i:check_scene",
)

SEQUENCE_KINDS = ("light", "gamma")
MOVABLE = ("point", "spot", "quad")  # light kinds with a position a light sequence moves


def check_scene(scene: Scene) -> None:
    """Every glossy material needs the γ range its PCA basis is baked over."""
    for name, material in scene.materials.items():
        if material.model != "lambert" and "gamma_range" not in material.params:
            raise PrtError(scene.path, f"materials.{name}.gamma_range: method d2i needs the "
                           "range of gamma its PCA basis covers, e.g. [3, 300]")


def parse_sequence(text: str) -> tuple[str, str | None, int]:
    """``light[:LIGHT]:N`` or ``gamma[:MATERIAL]:N`` -> (kind, LIGHT or MATERIAL or None,
    N)."""
    parts = text.split(":")
    if parts[0] not in SEQUENCE_KINDS or len(parts) not in (2, 3) or \
            not parts[-1].isdigit() or int(parts[-1]) < 1 or \
            (len(parts) == 3 and not parts[1]):
        raise PrtError(None, f"--frames {text}: expected light[:LIGHT]:N or "
                       "gamma[:MATERIAL]:N (N ≥ 1 frames; LIGHT an index into lights or "
                       "a quad light's object)")
    return parts[0], parts[1] if len(parts) == 3 else None, int(parts[-1])


def pick_light(scene: Scene, name: str | None) -> int:
    """The index of the light a light sequence moves: ``name`` an index into ``lights``
    or the ``object`` of a quad light; default the first light with a position."""
    movable = [i for i, light in enumerate(scene.lights) if light.type in MOVABLE]
    if name is None:
        if not movable:
            kinds = ", ".join(sorted({light.type for light in scene.lights})) or "none"
            raise NotApplicable(scene.path, "a light sequence needs a light with a position "
                                f"(point, spot or quad) to move; the scene's lights: {kinds}")
        return movable[0]
    named = [i for i, light in enumerate(scene.lights)
             if name == str(i) or light.params.get("object") == name]
    if not named:
        raise PrtError(scene.path, f"--frames light:{name}: no light {name!r} (an index "
                       f"0..{len(scene.lights) - 1} or a quad light's object)")
    if named[0] not in movable:
        raise PrtError(scene.path, f"--frames light:{name}: lights[{named[0]}] is a "
                       f"{scene.lights[named[0]].type} light; it has no position to move")
    return named[0]


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str) -> Sequence:
    """The edit kind, edited scenes, a label for each frame of ``spec`` and the path of
    the edit in words.

    ``light``: the light (see :func:`pick_light`) moves around a horizontal circle (the
    world xz plane) centred on its position (a quad: its corner), of radius 0.1 × the
    diagonal of the scene's bounding box, frame i at angle 2πi/N from +x towards +z
    (frame 0 is displaced by the radius along +x). A quad light's emitter object is
    drawn where the light is (pipeline/render/emitters.py).
    ``gamma``: material M's γ geometrically over its gamma_range (N = 1: its γ)."""
    kind, name, count = parse_sequence(spec)
    if kind == "light":
        index = pick_light(scene, name)
        light = scene.lights[index]
        geo = artifacts["geometry"].attrs
        radius = 0.1 * float(np.linalg.norm(np.subtract(geo["bbox_max"], geo["bbox_min"])))
        angles = 2 * np.pi * np.arange(count) / count
        offsets = [(radius * np.cos(a), 0.0, radius * np.sin(a)) for a in angles]
        key = "corner" if light.type == "quad" else "position"
        centre = ", ".join(f"{v:.4g}" for v in light.params[key])
        emitter = f"its emitter {light.params['object']!r} moves with it" \
            if light.params.get("object") else "a light without geometry: nothing visible moves"
        path = (f"lights[{index}] ({light.type}; {emitter}) moves around a horizontal "
                f"circle (xz plane) of radius {radius:.4g} scene units centred on its "
                f"{key} ({centre}): {count} frame(s) {360 / count:.4g}° apart, frame 0 at "
                "+x, turning towards +z")
        return (kind, [with_light_offset(scene, index, o) for o in offsets],
                [f"light {index} moved by ({o[0]:.3g}, {o[1]:.3g}, {o[2]:.3g})"
                 for o in offsets], path)
    return sequences.gamma_sweep(scene, name, count)
