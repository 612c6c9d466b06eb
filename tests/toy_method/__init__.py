"""A toy rendering method defined entirely under tests/: its own stage file, stage
modules, schemas, kernels, renderer and descriptor. Registered only where the
environment says ``PRT_PLUGINS=toy_method``; tests use it to show that a method plugs in
with no core file edited.

Stages: ``toy.shade`` (pixel tiles: the G-buffer normal's up component, clamped, through
an OpenCL kernel that includes a header) and ``toy.level`` (unchunked: the mean of
toy.shade). Frame: ``gain`` × shade + level, through an OpenCL kernel.
Option ``gain`` (float, 1.0). Sequences ``gain:N``: N frames with the gain 1..N.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.method import Method, Option

HERE = Path(__file__).resolve().parent

METHOD = Method(
    name="toy",
    description="test plug-in: shading by the up component of the normal",
    renderer="toy_method.render:ToyRenderer",
    reads=("gbuffer", "toy.shade", "toy.level"),
    reference="direct",
    options=(Option("gain", float, 1.0, "multiplies the shading"),),
    sequences="toy_method.render:sequence",
    main_sequences=("gain:2",),
    evaluate_sweep={"size": [8]},
    evaluate_size=8,
    lights=("point", "spot", "directional", "quad"),
    evaluate_reference_spp=16,
    stagefile=HERE / "stages.yaml",
    schema_dir=HERE / "schema",
    kernel_dir=HERE / "kernels",
)
