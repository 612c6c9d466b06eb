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

* ``budget`` (int, 320): coefficients per function at most (0: as stored, i.e. what
  the bake's ``triple.store_tolerance`` chose, at most ``triple.store_budget``). Budgets
  up to 320 top-only render on the dense path, 200–400× faster than the stored rows'
  sparse path. 320, the default, is the fastest within 5 % of the env-direct reference
  on the suite's scenes (decision 0041: bunny_grace 4.8 %, armadillo_forest 4.1 %,
  teapot_sunset 5.2 % against 4.9 % as stored, at 64²; 90–130 ms a 1024×768 frame on 2
  loaded CPU cores against 27–45 s as stored);
* ``selection`` (str, ``top-only``): which coefficients a budget keeps: ``top-only``
  (the first ``budget`` of the layout, coarse levels first; exact up to 320 from the
  stored rows) or ``adaptive`` (the largest by area-weighted magnitude);
* ``trace`` (str, ``auto``): who traces a new camera's rays: ``device`` (the project's
  BVH kernel, pipeline/device/bvh.py: on a GPU the rays never wait on the host's
  cores), ``embree`` (the host) or ``auto`` (the device on a GPU, Embree on a CPU,
  where it is the faster).

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
        Option("budget", int, 320, "coefficients per function at most (0: as stored)",
               least=0),
        Option("selection", str, "top-only", "top-only or adaptive: which a budget keeps",
               choices=("top-only", "adaptive")),
        Option("trace", str, "auto", "camera rays: device (the BVH kernel), embree (host) "
               "or auto (the device on a GPU)", choices=("device", "embree", "auto")),
    ),
    sequences="pipeline.methods.triple.hooks:sequence",
    sequence_forms=("rotate:N", "orbit:N", "gamma[:MATERIAL]:N"),
    main_sequences=("rotate:8",),
    # 20 and 80 coefficients top-only and adaptive, the stored rows (0; the selection
    # does not apply), and the default (320 top-only) added by prt evaluate: run-time
    # cuts of one bake. At 64² (1024-spp references: 3.1 % noise) the budgets took
    # 22 min on the 2 shared cores at load 15–20; studies/triple_accuracy.py studies 128²
    evaluate_sweep={"render.budget": [20, 80, 0], "render.selection": ["top-only", "adaptive"]},
    evaluate_size=64,
    evaluate_reference_spp=1024,
    lights=("environment",),
    features=("blends", "bumps"),
    check_scene="pipeline.methods.triple.hooks:check_scene",
    # run time: the map's turn, the camera (traced anew), the BRDFs; while prt view
    # drags, 80 coefficients (decision 0043), the default budget on release
    edits=("environment", "camera", "gamma", "specular", "albedo"),
    drag_options=(("budget", 80),),
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
