"""Method d2i's limits (pipeline/method.py ``Limit``): where its picture breaks down.

**Coefficients per pixel.** With the paper's proportional budgets D keeps
``truncate.d_coefficients`` Haar coefficients per pixel, pooled over its pixel block.
Below :data:`LEAST_D_COEFFICIENTS` the blocks (``truncate.d_block``²) show and sharp
indirect shadows turn bright: the surfaces of the spot-lit breakdown scene err 7.4 % at
100, 10.3 % at 50, 17.1 % at 25 (decision 0019).

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
