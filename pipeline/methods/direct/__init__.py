"""Method ``direct``: the scene's point, spot, directional and quad lights with shadows,
one reflection, from the baked G-buffer (render.py, over pipeline/render/direct.py). It
needs no precomputed transport: the baseline every other method's direct term shares,
and the method of a scene that names none."""

from __future__ import annotations

from pipeline.method import Method

METHOD = Method(
    name="direct",
    description="direct light only (point, spot, directional and quad lights, shadows)",
    renderer="pipeline.methods.direct.render:DirectRenderer",
    reads=("geometry", "gbuffer"),
    reference="direct",
    headline="rel_rmse",
    evaluate_sweep={"size": [64, 128]},
    evaluate_size=128,
    evaluate_reference_spp=1024,
    lights=("point", "spot", "directional", "quad"),
    features=("emitters",),
    edits=("light",),
    default=True,
)
