"""Method d2i's limits (pipeline/method.py ``Limit``): where its picture breaks down.

**Coefficients per pixel.** With the paper's proportional budgets D keeps
``truncate.d_coefficients`` Haar coefficients per pixel, pooled over its pixel block.
Below :data:`LEAST_D_COEFFICIENTS` the blocks (``truncate.d_block``²) show and sharp
indirect shadows turn bright: the surfaces of the spot-lit breakdown scene err 7.4 % at
100, 10.3 % at 50, 17.1 % at 25 (decision 0019).

**Gathers per pixel.** A gather ray leaves from a pixel's centre (stages/gather.py), so
a budget of many gathers per pixel shoots bunches of rays from few points. The Cornell
box at 64² (4,096 pixels, `python -m benchmarks run d2i.suite` and `prt evaluate
--sweep gather.count=...`): 2,048 / 4,096 / 8,192 / 16,384 gathers err 2.9 / 2.6 / 2.7 /
6.0 % (the indirect image 13.4 % at 16,384 against 5.3 % at 4,096, boxes' fronts and the
floor beside them), while at 96² 16,384 (1.8 per pixel) err 2.6 %. Above
:data:`MOST_GATHERS_PER_PIXEL` the check warns.

**Gathers found.** A gather ray that escapes is drawn again, up to 64 times per sample
(stages/gather.py): in a scene open to the sky fewer samples than ``gather.count`` land
on a surface, and the indirect light's noise grows as 1/√found. Where fewer than
:data:`LEAST_FOUND_FRACTION` of them were found (the indirect error about 15 % above
what the count promises, or no indirect light at all) the check warns.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pipeline.scene.model import Scene

LEAST_D_COEFFICIENTS = 50
MOST_GATHERS_PER_PIXEL = 2.0  # 2 per pixel: 2.7 %, 4 per pixel: 6.0 % (Cornell at 64²)
LEAST_FOUND_FRACTION = 0.75  # 1/√0.75 = 1.15: the indirect noise 15 % above the count's


def coefficients_per_pixel(scene: Scene, params: Mapping[str, Any],
                           artifacts: Mapping[str, Any] | None) -> str | None:
    """Whether D keeps fewer than :data:`LEAST_D_COEFFICIENTS` per pixel."""
    kept = int(params["truncate.d_coefficients"])
    if params["truncate.budget"] != "proportional" or kept >= LEAST_D_COEFFICIENTS:
        return None
    block = int(params["truncate.d_block"])
    return (f"truncate.d_coefficients {kept} < {LEAST_D_COEFFICIENTS}: the {block}×{block} "
            "pixel blocks of D show and sharp indirect shadows turn bright (the surfaces "
            "of decision 0019's scene: 7.4 % at 100, 17.1 % at 25); raise it")


def gathers_per_pixel(scene: Scene, params: Mapping[str, Any],
                      artifacts: Mapping[str, Any] | None) -> str | None:
    """Whether ``gather.count`` exceeds :data:`MOST_GATHERS_PER_PIXEL` per pixel of the
    image the scene bakes."""
    count = int(params["gather.count"])
    pixels = scene.camera.width * scene.camera.height
    if count <= MOST_GATHERS_PER_PIXEL * pixels:
        return None
    return (f"gather.count {count} is {count / pixels:.1f} per pixel of the "
            f"{scene.camera.width}×{scene.camera.height} image (above "
            f"{MOST_GATHERS_PER_PIXEL:g}): gathers leave from the pixels' centres, and the "
            "indirect light errs more (Cornell at 64²: 6.0 % at 4 per pixel against 2.7 % "
            "at 2); lower gather.count or render a larger image")


def gathers_found(scene: Scene, params: Mapping[str, Any],
                  artifacts: Mapping[str, Any] | None) -> str | None:
    """Whether the gather stage found fewer than :data:`LEAST_FOUND_FRACTION` of the
    samples asked for."""
    if artifacts is None:
        return None
    attrs = artifacts["d2i.gather"].attrs
    found, asked = int(attrs["count"]), int(attrs["requested"])
    if found >= LEAST_FOUND_FRACTION * asked:
        return None
    effect = "no indirect light at all" if found == 0 else \
        f"indirect noise {(asked / found) ** 0.5:.1f}× what gather.count promises"
    return (f"{found} of {asked} gather samples landed on a surface (rays escaped: the "
            f"scene is open), {effect}; close the scene or raise gather.count")
