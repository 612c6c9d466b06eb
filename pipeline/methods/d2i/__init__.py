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

from pathlib import Path

from pipeline.method import Component, Limit, Method, Option

METHOD = Method(
    name="d2i",
    stagefile=Path(__file__).with_name("stages.yaml"),
    description="paper 000: direct-to-indirect transfer, PCA-linearized BRDF editing",
    renderer="pipeline.methods.d2i.render:D2iRenderer",
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
    sequences="pipeline.methods.d2i.hooks:sequence",
    sequence_forms=("light[:LIGHT]:N", "gamma[:MATERIAL]:N"),
    main_sequences=("light:8", "gamma:8"),
    evaluate_sweep={"gather.count": [4096, 16384]},
    evaluate_size=96,
    evaluate_reference_spp=1024,
    lights=("point", "spot", "directional", "quad"),
    features=("emitters",),
    check_scene="pipeline.methods.d2i.hooks:check_scene",
    # run time: lights and the BRDFs (prt view drags them in light- and BRDF-edit mode)
    edits=("light", "gamma", "specular", "albedo"),
    edit_modes={"light": "light", "gamma": "gamma", "specular": "gamma", "albedo": "gamma"},
    limits=(
        Limit("coefficients-per-pixel", "below 50 coefficients of D per pixel "
              "(truncate.d_coefficients) the pixel blocks show and sharp indirect shadows "
              "turn bright", "pipeline.methods.d2i.limits:coefficients_per_pixel"),
        Limit("gathers-per-pixel", "more than 2 gathers per pixel (gather.count against "
              "the image) shoot bunches of rays from the same pixel centres and the "
              "indirect light errs more: lower gather.count or render larger",
              "pipeline.methods.d2i.limits:gathers_per_pixel"),
        Limit("gathers-found", "in a scene open to the sky gather rays escape: fewer than "
              "three quarters of gather.count found make the indirect light noisier, none "
              "leaves it out", "pipeline.methods.d2i.limits:gathers_found"),
    ),
)
