"""Who traces a bake's visibility rays: Embree on the host's cores or the project's BVH
kernel on the OpenCL device (pipeline/device/bvh.py) — the stage parameter
``bake.device`` (stages.yaml), set by ``prt run`` / ``prt render --bake-device``.

The two answer the same question by different float32 formulas, so a ray that grazes an
edge within rounding may be blocked for one and free for the other (tests/test_bvh.py
bounds how rarely): a bake on each differs in those bits. The parameter is therefore in
the keys of the stages that read it, and the keys hold what was *used* — ``device`` or
``embree`` — never ``auto``: the plan (pipeline/engine/planning.py ``stage_params``)
turns ``auto`` into the choice for this machine's OpenCL device with :func:`resolve`
(the device on a GPU, where it is the faster by far; Embree on a CPU device, where
Embree is the faster, decision 0047), so a CPU bake and a GPU bake of one scene never
take each other's place silently.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.errors import PrtError

PARAM = "bake.device"
CHOICES = ("auto", "device", "embree")  # what a user may ask for
TRACERS = ("device", "embree")          # what a stage is given

_TRACERS: dict[str, tuple[str, Any]] = {}  # choice -> (geometry key, its tracer)


def resolve(choice: Any, path: Any = None, name: str = "--bake-device") -> str:
    """``device`` or ``embree`` for a user's ``choice`` (:data:`CHOICES`; an error names
    ``path`` and ``name``): ``auto`` is the device where the chosen OpenCL device
    (pipeline/device/devices.py) is a GPU, else Embree (also where no device works: the
    bake's kernels then report that)."""
    if choice not in CHOICES:
        raise PrtError(path, f"{name}: {choice!r}: expected one of {', '.join(CHOICES)}")
    if choice != "auto":
        return choice
    return "device" if device_is_gpu() else "embree"


def device_is_gpu() -> bool:
    """Whether the OpenCL device the project uses is a GPU (False where none works)."""
    from pipeline.device import cl

    try:
        import pyopencl as pcl

        return bool(cl.device().type & pcl.device_type.GPU)
    except PrtError:
        return False


def auto_choice() -> str:
    """One line: what ``auto`` chooses on this machine and why (``prt devices``)."""
    from pipeline.device import cl

    try:
        cl.device()
    except PrtError:
        return "bake rays: embree (auto: no OpenCL device works)"
    if resolve("auto") == "device":
        return "bake rays: device (auto: the OpenCL device is a GPU)"
    return "bake rays: embree (auto: the OpenCL device is not a GPU; Embree is faster there)"


def bake_tracer(choice: str, key: str, vertices: np.ndarray, faces: np.ndarray,
                embree: Any = None) -> Any:
    """The tracer of a stage's visibility rays over the triangles ``faces`` (F, 3) of
    ``vertices`` (V, 3) of the geometry artifact whose key is ``key``: for ``embree`` a
    pipeline.device.raytrace.RayTracer (``embree`` itself when the caller has one), for
    ``device`` a pipeline.device.bvh.DeviceRayTracer; built once per process, geometry
    and choice, shared by the chunks. Both answer ``occluded(origins, directions,
    distances, threads)`` and ``intersect``, and have ``threads``."""
    if choice not in TRACERS:
        raise PrtError(PARAM, f"{choice!r}: expected device or embree (auto is resolved "
                       "before a bake: pipeline/device/bake_tracer.py)")
    if choice == "embree" and embree is not None:
        return embree
    if _TRACERS.get(choice, ("", None))[0] != key:
        from pipeline.device.bvh import DeviceRayTracer
        from pipeline.device.raytrace import RayTracer

        kind = DeviceRayTracer if choice == "device" else RayTracer
        _TRACERS[choice] = (key, kind(vertices, faces))
    return _TRACERS[choice][1]
