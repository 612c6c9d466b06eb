"""Method ``sg``: view-dependent glossy transport as sums of spherical Gaussians per
vertex and view, integrated against a Gaussian-prefiltered environment map (paper 003;
issue 17).

Stages (this folder's stages.yaml, ``sg.*``): ``sg.env_prefilter`` (the environment map convolved
with normalised SGs of increasing σ, pipeline/methods/sg/stages/env_prefilter.py), ``sg.fit`` (per
vertex and each of 92 views, the glossy transport fitted by Gaussians,
pipeline/methods/sg/stages/fit.py: direct + indirect glossy computed in the chunk and fitted
there, never stored; flips relaxed within its vertex batches), ``sg.relax`` (the
relaxation over every mesh edge, pipeline/methods/sg/stages/relax.py: the lobes a frame reads)
and ``sg.diffuse`` (the diffuse transfer in SH with shadows and
interreflection, pipeline/methods/sg/stages/diffuse.py); shared: ``geometry``. Renderer:
pipeline/methods/sg/render.py + kernels/sg/sg_render.cl.

Run-time options: ``lambda_blend`` (str, ``log``): how a lobe's sharpness λ is blended
over the 3 views × 3 vertices, ``log`` (linear in log σ) or ``linear``; ``component``
(str, ``all``): ``glossy`` or ``diffuse`` render the light reflected by the lobes or by
the SH term alone, without the background (``prt evaluate`` measures each against
``prt reference --transport first-glossy --lobe glossy|diffuse``).

Sequences (``--frames``): ``rotate:N`` turns the environment map once around +y,
``orbit:N`` moves the camera around its look_at point (as method triple's).

The lobe mathematics (pipeline/math/sg.py, kernels/sg/sg.h) and the batched fit
(pipeline/methods/sg/fit.py) are in place and tested (tests/test_sg.py, test_sg_fit.py).

Scene requirements: exactly one environment light (other light kinds are refused up
front: methods ``direct`` and ``d2i`` render them).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pipeline.errors import PrtError
from pipeline.method import Component, Method, Option, check_one_environment
from pipeline.render import sequences
from pipeline.render.sequences import Sequence
from pipeline.scene import Scene
from pipeline.store import Artifact

METHOD = Method(
    name="sg",
    stagefile=Path(__file__).with_name("stages.yaml"),
    description="paper 003: glossy transport per vertex and view as spherical Gaussians, "
                "a Gaussian-prefiltered environment",
    renderer="pipeline.methods.sg.render:sg_renderer",
    reads=("geometry", "sg.relax", "sg.diffuse", "sg.env_prefilter"),
    options=(Option("lambda_blend", str, "log",
                    "log or linear: how a lobe's sharpness is blended between views",
                    choices=("log", "linear")),
             Option("component", str, "all",
                    "all, glossy or diffuse: the whole frame, or the light reflected by "
                    "the lobes or by the SH term alone (no background)",
                    choices=("all", "glossy", "diffuse"))),
    sequences="pipeline.methods.sg:sequence",
    sequence_forms=("rotate:N", "orbit:N"),
    main_sequences=("rotate:8", "orbit:8"),
    # paper 003 models direct and indirect glossy at the first vertex and diffuse light
    # with shadows and interreflection after it: the first-glossy transport (full BRDF
    # at the first surface, Lambertian after); its glossy and diffuse parts measured
    # apart against that transport with one lobe of the BRDF at the first surface
    reference="first-glossy",
    headline="rel_rmse_surfaces",
    components={part: Component(transport="first-glossy", options=(("component", part),),
                                lobe=part) for part in ("glossy", "diffuse")},
    evaluate_sweep={"sg.fit_max_lobes": [1, 3]},
    evaluate_size=64,
    evaluate_reference_spp=1024,
    lights=("environment",),
    check_scene="pipeline.methods.sg:check_scene",
)


def check_scene(scene: Scene) -> None:
    """Exactly one environment light, whose map reads as a valid latitude-longitude map,
    and glossy lobes the fit's grid can sample (checked before anything is baked)."""
    check_one_environment(scene, "sg")
    check_lobe_widths(scene)


def check_lobe_widths(scene: Scene) -> None:
    """PrtError naming the material when a glossy lobe is too sharp for the fit's grid.

    sg.fit tabulates each vertex's transport on the lat-long grid ``sg.fit_grid`` =
    [rows, columns] (pole +y): samples Δθ = π/(rows − 1) and Δφ = 2π/columns apart, so a
    direction lies up to d = ½ √(Δθ² + Δφ²) from the nearest sample (on the equator).
    A lobe whose half width at half maximum (at normal view, measured on the BRDF) is
    under d/2 can fall between the samples: its tabulation is a fraction of its peak, or
    zero (γ 20000 on a [9, 18] grid divided by a zero norm mid-bake)."""
    import math

    import numpy as np

    from pipeline import job
    from pipeline.math.brdf import glossy, scene_brdfs
    from pipeline.runner import stage_params

    rows, columns = (int(n) for n in stage_params(job.stages(), scene)["sg.fit_grid"])
    spacing = 0.5 * math.hypot(math.pi / max(rows - 1, 1), 2 * math.pi / max(columns, 1))
    used = sorted({o.material for o in scene.objects.values()})
    t = np.geomspace(1e-5, math.pi / 2, 4000)
    wi = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)  # away from the normal
    wo = np.array([0.0, 0.0, 1.0])
    for name, brdf in zip(used, scene_brdfs(scene, used), strict=True):
        if brdf.model == "lambert" or max(brdf.specular) <= 0:
            continue
        lobe = glossy(wi, wo, brdf)
        below = np.flatnonzero(lobe < 0.5 * lobe[0])
        width = t[below[0]] if len(below) else math.pi / 2
        if width < 0.5 * spacing:
            raise PrtError(scene.path, f"materials.{name}: its glossy lobe (half width "
                           f"{math.degrees(width):.2g}° at normal view) is too sharp for "
                           f"sg.fit_grid {[rows, columns]}, whose samples lie up to "
                           f"{math.degrees(spacing):.2g}° apart: give a broader lobe (a "
                           f"smaller gamma) or a finer sg.fit_grid (about "
                           f"{_rows_for(width)} rows)")


def _rows_for(width: float) -> int:
    """The rows (columns = 2 × rows) whose largest distance to a sample is 2 × ``width``
    radians: d = ½ √(Δθ² + Δφ²) with Δθ ≈ Δφ ≈ π/(rows − 1) gives rows ≈ π/(2√2 w) + 1."""
    import math

    return math.ceil(math.pi / (2 * math.sqrt(2) * width)) + 1


def sequence(scene: Scene, artifacts: Mapping[str, Artifact], spec: str) -> Sequence:
    """``rotate:N`` (the environment turns about +y) or ``orbit:N`` (the camera circles
    its look_at point; pipeline/render/sequences.py)."""
    kind, _, count = spec.partition(":")
    if kind not in ("rotate", "orbit") or not count.isdigit() or int(count) < 1:
        raise PrtError(None, f"--frames {spec}: expected rotate:N or orbit:N (N ≥ 1 frames)")
    return (sequences.rotate if kind == "rotate" else sequences.orbit)(scene, int(count))
