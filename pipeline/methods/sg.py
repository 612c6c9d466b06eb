"""Method ``sg``: view-dependent glossy transport as sums of spherical Gaussians per
vertex and view, integrated against a Gaussian-prefiltered environment map (paper 003;
issue 17). A skeleton so far: it bakes what exists and refuses to render.

Stages (stages.yaml, ``sg.*``): ``sg.env_prefilter`` (the environment map convolved
with normalised SGs of increasing σ, pipeline/stages/env_prefilter.py), ``sg.diffuse``
(per vertex, the diffuse transfer in order-5 SH with shadows and interreflections,
pipeline/stages/sg_diffuse.py). Not built yet: ``sg.fit`` (per vertex and each of 92
views, the glossy transport of pipeline/math/sg_transport.py fitted by Gaussians,
pipeline/math/sg_fit.py),
and the renderer: ``prt render --method sg`` bakes the stages above and then stops
with a one-line error saying so; no frame is written.

The lobe mathematics (pipeline/math/sg.py, kernels/sg.h) and the batched fit
(pipeline/math/sg_fit.py) are in place and tested (tests/test_sg.py, test_sg_fit.py).

Scene requirements: exactly one environment light (other light kinds are refused up
front: methods ``direct`` and ``d2i`` render them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NoReturn

from pipeline.errors import PrtError
from pipeline.images import read_environment
from pipeline.method import Method
from pipeline.scene import Scene
from pipeline.store import Artifact

BUILT = ("sg.env_prefilter", "sg.diffuse")
NOT_BUILT = ("sg.fit", "the renderer")

METHOD = Method(
    name="sg",
    description="paper 003: glossy transport per vertex and view as spherical Gaussians, "
                "a Gaussian-prefiltered environment (skeleton: bakes the prefilter only)",
    renderer="pipeline.methods.sg:sg_renderer",
    reads=BUILT,
    # paper 003 models direct and indirect glossy at the first vertex and diffuse light
    # with shadows and interreflection: of the reference transports, the full one
    reference="full",
    headline="rel_rmse_surfaces",
    lights=("environment",),
    check_scene="pipeline.methods.sg:check_scene",
    renders=False,  # a skeleton until sg.fit and the renderer exist
)


def check_scene(scene: Scene) -> None:
    """Exactly one environment light, whose map reads as a valid latitude-longitude map
    (checked before anything is baked)."""
    count = sum(light.type == "environment" for light in scene.lights)
    if count != 1:
        raise PrtError(scene.path, f"lights: method sg renders exactly one environment "
                       f"light; the scene has {count}")
    read_environment(scene.environment_file())


def sg_renderer(scene: Scene, artifacts: Mapping[str, Artifact], **options: Any) -> NoReturn:
    """Refuses: the stages a frame needs are not built yet (issue 17)."""
    raise PrtError(scene.path, f"method sg cannot render yet: {', '.join(NOT_BUILT)} "
                   f"are not built (issue 17); baked so far: {', '.join(artifacts)}")
