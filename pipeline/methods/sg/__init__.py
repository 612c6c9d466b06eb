"""Method ``sg``: view-dependent glossy transport as sums of spherical Gaussians per
vertex and view, integrated against a Gaussian-prefiltered environment map (paper 003;
issue 17).

Stages (this folder's stages.yaml, ``sg.*``): ``sg.env_prefilter`` (the environment map convolved
with normalised SGs of increasing σ, pipeline/methods/sg/stages/env_prefilter.py), ``sg.fit`` (per
vertex and each of 92 views, the glossy transport fitted by Gaussians,
pipeline/methods/sg/stages/fit.py: direct + indirect glossy computed in the chunk and fitted
there, never stored; flips relaxed within its vertex batches), ``sg.relax`` (the
relaxation over every mesh edge, pipeline/methods/sg/stages/relax.py: the lobes the
``normal`` options vertex, pixel and ratio read), ``sg.visibility`` (per vertex, its
visibility as an octahedral mip pyramid and its occluders' diffuse transfer: what the
default ``normal=visibility`` reads, pipeline/methods/sg/visibility.py),
``sg.source_visibility`` (per vertex, what it sees of each of the map's bright sources
at each turn of the map about +y, pipeline/methods/sg/source_rings.py) and
``sg.diffuse`` (the diffuse transfer in SH with shadows and interreflection,
pipeline/methods/sg/stages/diffuse.py); shared: ``geometry``. A bake runs the stages the
frame's options read (``option_reads``): the default fits no lobes. Renderer:
pipeline/methods/sg/render.py + kernels/sg/sg_render.cl.

Run-time options: ``lambda_blend`` (str, ``log``): how a lobe's sharpness λ is blended
over the 3 views × 3 vertices, ``log`` (linear in log σ) or ``linear``; ``component``
(str, ``all``): ``glossy`` or ``diffuse`` render the light reflected by the lobes or by
the SH term alone, without the background (``prt evaluate`` measures each against
``prt reference --transport first-glossy --lobe glossy|diffuse``); ``normal`` (str,
``visibility``): ``vertex``, the lobes as fitted at the vertices (paper 003), or ``pixel``: each
vertex's lobes about its mirror direction turned to the pixel's (its blended normal's)
so that the highlight follows the pixel's normal (decision 0039: no gain on bunny_sg
and dragon_sg, 8x the shading kernel's time; 23.5 -> 17.2 % on a coarse ball), or
``ratio``: the BRDF's lobe at the pixel's normal, the vertices' lobes kept as a
visibility ratio to the unshadowed light (decision 0042; pipeline/methods/sg/brdf_lobe.py),
or ``visibility`` (the default, decision 0046): no lobes, the BRDF's lobe at the pixel's
normal split into 7 Gaussians, each's light from the prefiltered map times the corners'
visibility looked up in their maps, plus the occluders' diffuse light; the map's bright
sources taken apart, each by the exact BRDF at its direction (decision 0048,
pipeline/methods/sg/sources.py; ``sg.env_prefilter`` stores them and the residual's
stack), their glossy and diffuse light shadowed by what each vertex sees of them
(decision 0049: ``sg.source_visibility`` where the map turns about +y, the maps about
any other axis).

Sequences (``--frames``): ``rotate:N`` turns the environment map once around +y,
``orbit:N`` moves the camera around its look_at point (as method triple's).

The lobe mathematics (pipeline/math/sg.py, kernels/sg/sg.h) and the batched fit
(pipeline/methods/sg/fit.py) are in place and tested (tests/test_sg.py, test_sg_fit.py).

Scene requirements: exactly one environment light (other light kinds are refused up
front: methods ``direct`` and ``d2i`` render them).
"""

from __future__ import annotations

from pathlib import Path

from pipeline.method import Component, Limit, Method, Option

METHOD = Method(
    name="sg",
    stagefile=Path(__file__).with_name("stages.yaml"),
    description="paper 003: a Gaussian-prefiltered environment, per-vertex transport; "
                "by default the BRDF per pixel against per-vertex visibility maps (the "
                "paper's fitted Gaussian lobes: --option normal=vertex)",
    renderer="pipeline.methods.sg.render:sg_renderer",
    reads=("geometry", "sg.diffuse", "sg.env_prefilter"),
    # the fitted lobes (sg.fit, minutes to an hour) only where normal uses them; the
    # default reads the vertices' visibility instead (seconds; decision 0046)
    option_reads=(*(("normal", n, ("sg.relax",)) for n in ("vertex", "pixel", "ratio")),
                  ("normal", "visibility", ("sg.visibility", "sg.source_visibility"))),
    options=(Option("lambda_blend", str, "log",
                    "log or linear: how a lobe's sharpness is blended between views",
                    choices=("log", "linear")),
             Option("normal", str, "visibility",
                    "vertex, pixel, ratio or visibility: the lobes as fitted at the "
                    "vertex (paper 003), turned towards the pixel's blended normal "
                    "(decision 0039), the BRDF at the pixel's normal by a ratio of "
                    "unshadowed radiances (decision 0042), or the BRDF at the pixel's "
                    "normal against each vertex's visibility map, no lobes (decision 0046)",
                    choices=("vertex", "pixel", "ratio", "visibility")),
             Option("component", str, "all",
                    "all, glossy or diffuse: the whole frame, or the light reflected by "
                    "the lobes or by the SH term alone (no background)",
                    choices=("all", "glossy", "diffuse"))),
    sequences="pipeline.methods.sg.hooks:sequence",
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
    evaluate_sweep={"sg.visibility_resolution": [16, 32]},
    evaluate_size=64,
    evaluate_reference_spp=1024,
    lights=("environment",),
    check_scene="pipeline.methods.sg.hooks:check_scene",
    edits=("environment", "camera"),  # run time; the lobes are fitted for the BRDFs
    limits=(
        Limit("small-sources", "a map holding three quarters or more of the light its "
              "bright sources (sg.source_min_share each) leave in sources smaller than "
              "one cell of the diffuse term's SH (4π/n² sr at sg.diffuse_order n) casts "
              "shadows sg blurs into a dark blob: a lower sg.source_min_share takes more "
              "apart, method triple keeps them sharp",
              "pipeline.methods.sg.limits:small_sources"),
        Limit("visibility-folds", "under normal=visibility, where a surface folds faster "
              "than its vertices (neighbouring vertices' visibility maps differ by more "
              "than 5 % on average) its glossy highlights' shadows smear: "
              "objects.NAME.subdivide adds vertices",
              "pipeline.methods.sg.limits:visibility_folds"),
        Limit("vertex-spacing", "light is carried per vertex: where a mesh's edges span "
              "more than 6 pixels on screen (median) its shadows and highlights blur "
              "across the triangles: a finer mesh or a smaller image",
              "pipeline.methods.sg.limits:vertex_spacing"),
    ),
)
