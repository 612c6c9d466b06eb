"""Method ``triple``: all-frequency environment lighting with shadows by triple products
of spherical Haar wavelets in local frames (paper 004, building on Ng et al. 2004).

Stages (this folder's stages.yaml, ``triple.*``): ``triple.atlas`` (a UV atlas per object, texels →
surface points), ``triple.visibility`` (per texel, visibility in its local frame as
wavelet rows, texel tiles), ``triple.light_rotations`` (the environment map in every
frame of the rotation grid), ``triple.brdf_tables`` (per material, the glossy term × cos
over a grid of local views, and the diffuse row); shared: ``geometry``. The bake does
not depend on the camera's pose (only the texture sizes read the scene camera), on the
map's rotation or scale, or on the materials' albedo and ρs. Renderer:
pipeline/methods/triple/render.py.

Run-time options (``prt render --option NAME=VALUE``):

* ``budget`` (int, 0): coefficients per function at most (0: as stored, i.e. what the
  bake's ``triple.store_tolerance`` chose, at most ``triple.store_budget``). Budgets up to
  320 top-only render on the dense path, about 60× faster than the stored rows' sparse
  path and less accurate: on bunny_grace at 128², shading 16 ms (320) and 7 ms (80)
  against 970 ms as stored, frames 4.7 % and 16 % (relative L² over the surfaces) from
  the stored rows' (decision 0024) — ``budget=320`` for interactive sequences;
* ``selection`` (str, ``top-only``): which coefficients a budget keeps: ``top-only``
  (the first ``budget`` of the layout, coarse levels first; exact up to 320 from the
  stored rows) or ``adaptive`` (the largest by area-weighted magnitude).

Sequences (``--frames``): ``rotate:N`` turns the environment map once around +y
(N frames 360°/N apart, from the scene's rotation); ``orbit:N`` moves the camera once
around a horizontal circle about its look_at point (radius and height kept);
``gamma[:MATERIAL]:N`` sweeps a glossy material's γ geometrically over its
``gamma_range`` (else [γ/4, 4γ]), each new γ's table re-sampled at run time.

Surface detail (paper 004 §4.2, run time: nothing is re-baked): a material's ``blend``
with a second material by a texture and its ``bump`` map (pipeline/render/surface_detail.py).

Scene requirements: exactly one environment light (other light kinds are refused up
front: methods ``direct`` and ``d2i`` render them).
"""

from __future__ import annotations

from pathlib import Path

from pipeline.method import Limit, Method, Option

METHOD = Method(
    name="triple",
    stagefile=Path(__file__).with_name("stages.yaml"),
    description="paper 004: environment light with all-frequency shadows, wavelet triple "
                "products in local frames",
    renderer="pipeline.methods.triple.render:TripleRenderer",
    reads=("geometry", "triple.atlas", "triple.visibility", "triple.light_rotations",
           "triple.brdf_tables"),
    reference="env-direct",
    headline="rel_rmse_surfaces",
    options=(
        Option("budget", int, 0, "coefficients per function at most (0: as stored)",
               least=0),
        Option("selection", str, "top-only", "top-only or adaptive: which a budget keeps",
               choices=("top-only", "adaptive")),
    ),
    sequences="pipeline.methods.triple.hooks:sequence",
    sequence_forms=("rotate:N", "orbit:N", "gamma[:MATERIAL]:N"),
    main_sequences=("rotate:8",),
    # issue 16: 20, 80, 320 coefficients top-only and adaptive, and the default (as
    # stored) added by prt evaluate; run-time cuts of one bake. At 64² (1024-spp
    # references: 3.1 % noise against errors ≥ 9.8 %) the 7 budgets took 22 min on the
    # 2 shared cores at load 15–20; studies/triple_accuracy.py studies 128²
    evaluate_sweep={"render.budget": [20, 80, 320], "render.selection": ["top-only", "adaptive"]},
    evaluate_size=64,
    evaluate_reference_spp=1024,
    lights=("environment",),
    features=("blends", "bumps"),
    check_scene="pipeline.methods.triple.hooks:check_scene",
    limits=(
        Limit("texels-per-pixel", "an object seen with fewer than 1.5 texels of its atlas "
              "per pixel (a camera closer, or an image larger, than baked for; a texture "
              "capped at triple.texture_max) shows texel blocks and aliased contact "
              "shadows: bake for the view or raise triple.texels_per_pixel",
              "pipeline.methods.triple.limits:texels_per_pixel"),
        Limit("atlas-padding", "an atlas less than a quarter covered (a detailed mesh in a "
              "small texture: many small charts, each padded) loses surface detail and "
              "darkens: raise triple.texels_per_pixel or simplify the mesh",
              "pipeline.methods.triple.limits:atlas_padding"),
    ),
)
