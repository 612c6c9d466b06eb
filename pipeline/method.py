"""Rendering methods as plug-ins: the descriptor and the registry.

A method (paper 000's ``d2i``, the ``direct`` baseline, and whatever comes next) is a
module that defines ``METHOD = Method(...)``. The core (cli, job, evaluate) reads the
registry and never names a method. Plug-ins are found

* in the package ``pipeline.methods`` (every module there is a plug-in), and
* in the modules named by the environment variable ``PRT_PLUGINS`` (comma-separated
  importable module names: a method kept outside the project, e.g. under ``tests/``).

A plug-in's own stages (a stage file in stages.yaml's format), schemas and kernels are
found through its descriptor; the project's stages.yaml declares the built-in methods'
stages, namespaced ``<method>.<stage>``. A scene lists the methods it is baked for under
``methods:`` (default: :data:`DEFAULT_METHODS`); ``prt run`` bakes only what those read.
"""

from __future__ import annotations

import importlib
import math
import os
import pkgutil
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from pipeline.errors import PrtError
from pipeline.images import read_environment
from pipeline.math.brdf import MATERIAL_PARAMETERS, specular_albedo_bound
from pipeline.scene import Scene
from pipeline.searchpath import add_kernel_dir, add_schema_dir

# Methods of a scene that names none (``methods:`` absent).
DEFAULT_METHODS = ("direct",)
# Every material model (BRDF) of the scene format: what a method renders unless it says.
ALL_MATERIALS = tuple(MATERIAL_PARAMETERS)
# Scene features beyond light kinds and materials that a method renders only when it
# declares them (``Method.features``), each with what it is.
FEATURES = {
    "emitters": "the emitting object of a quad light (its radiance seen by the camera)",
    "blends": "a material blended with another by a texture (materials.NAME.blend)",
    "bumps": "a bump map (materials.NAME.bump)",
}


class NotApplicable(PrtError):
    """Raised by a method's ``sequences`` function when the scene has nothing the
    sequence edits (no light that can move, no glossy material): ``prt run`` skips that
    main sequence, saying why; ``prt render --frames`` reports it as an error."""


@dataclass(frozen=True)
class Option:
    """A run-time option of a method's renderer (``prt render --option NAME=VALUE``):
    its name, type (int, float, str), default and one-line help; a number's ``least``
    value, a text's ``choices``."""

    name: str
    type: type
    default: Any
    help: str
    least: float | None = None
    choices: tuple[str, ...] = ()

    def parse(self, text: str) -> Any:
        try:
            value = self.type(text)
        except ValueError:
            raise PrtError("--option", f"{self.name}={text!r}: expected a value of type "
                           f"{self.type.__name__}") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise PrtError("--option", f"{self.name}={text!r}: expected a finite number")
        if self.least is not None and value < self.least:
            raise PrtError("--option", f"{self.name}={text!r}: expected a number >= "
                           f"{self.least:g}")
        if self.choices and value not in self.choices:
            raise PrtError("--option", f"{self.name}={text!r}: expected one of "
                           f"{', '.join(self.choices)}")
        return value


@dataclass(frozen=True)
class Component:
    """A part of a method's image that evaluate measures on its own, against the
    reference transport ``transport`` with ``lobe`` of the BRDF at the first surface
    (pipeline/reference.py LOBES): the method's frame less the frame of ``subtract`` (a
    method sharing its shader for the rest; d2i: its indirect light), or, without
    ``subtract``, the method's frame with the run-time ``options`` (sg: its glossy
    lobes, ``(("component", "glossy"),)``)."""

    transport: str
    subtract: str | None = None
    options: tuple[tuple[str, Any], ...] = ()
    lobe: str = "all"


@dataclass(frozen=True)
class Method:
    """What a method plug-in declares.

    ``renderer``: ``"module:factory"``; ``factory(scene, artifacts, **options)`` returns
    a renderer: a callable ``(scene) -> Frame``, loaded once from ``artifacts`` (the
    opened artifacts of ``reads``, by stage name) that renders edited scenes. It may
    also have ``edit_mode(kind) -> callable(scene) -> Frame``, a faster path for a
    sequence of one kind of edit.
    ``reads``: the stages whose artifacts a frame reads (what ``prt run`` bakes, with
    their upstream; the frame's storage; its cache key).
    ``reference``: the reference transport its frames are measured against;
    ``headline``: the error its charts lead with (``rel_rmse``, or
    ``rel_rmse_surfaces`` over the pixels not seeing an emitter).
    ``components``: images measured separately (name -> Component).
    ``options``: the renderer's run-time options.
    ``sequences``: ``"module:function"``; ``function(scene, artifacts, spec)`` returns
    (kind, edited scenes, labels) for a ``--frames`` spec, optionally with a fourth
    item, a sentence describing the edit's path (printed, and kept in the sequence's
    record); it raises PrtError for a bad spec, :class:`NotApplicable` when the scene
    has nothing to edit.
    ``sequence_forms``: every ``--frames`` spec form the sequences function reads
    (``prt methods`` and ``prt render --help`` list them).
    ``main_sequences``: the sequences ``prt run`` renders beside the frame.
    ``evaluate_sweep``, ``evaluate_size``, ``evaluate_reference_spp``: what ``prt
    evaluate`` runs without options (bounded: a few minutes on two cores): the sweep, on
    the scene resized to ``evaluate_size`` pixels wide, references capped at that spp.
    ``lights``: the light kinds (scene ``lights[].type``) the method renders; a scene
    with another kind, or with none of these, is refused before anything is baked.
    ``materials``: the material models (BRDFs, scene ``materials.*.model``) it renders
    (default: every model); ``features``: the scene features of :data:`FEATURES` it
    renders. A scene using another is refused before anything is baked, naming the
    methods that render it.
    ``check_scene``: ``"module:function"`` raising PrtError if the method cannot render
    the scene for another reason (e.g. a material lacks a setting it needs); it may
    return notes (a list of strings), shown before the bake and in ``--json`` output.
    ``stagefile``, ``schema_dir``, ``kernel_dir``: a plug-in's own stages, schemas and
    kernels (the built-in methods' live in the project's files).
    ``renders``: False for a plug-in whose renderer is not built yet (it bakes, then
    says so): refusals never name it among the methods that render something.
    """

    name: str
    description: str
    renderer: str
    reads: tuple[str, ...]
    reference: str
    headline: str = "rel_rmse"
    components: dict[str, Component] = field(default_factory=dict)
    options: tuple[Option, ...] = ()
    sequences: str | None = None
    sequence_forms: tuple[str, ...] = ()
    main_sequences: tuple[str, ...] = ()
    evaluate_sweep: dict[str, list[Any]] = field(default_factory=dict)
    evaluate_size: int | None = None
    evaluate_reference_spp: int = 1024
    lights: tuple[str, ...] = ()
    materials: tuple[str, ...] = ALL_MATERIALS
    features: tuple[str, ...] = ()
    check_scene: str | None = None
    stagefile: Path | None = None
    schema_dir: Path | None = None
    kernel_dir: Path | None = None
    renders: bool = True

    def option_values(self, given: dict[str, str]) -> dict[str, Any]:
        """Defaults overridden by ``given`` (NAME -> text), parsed; unknown names fail."""
        known = {o.name: o for o in self.options}
        unknown = sorted(set(given) - set(known))
        if unknown:
            raise PrtError("--option", f"method {self.name} has no option {unknown[0]!r} "
                           f"(options: {', '.join(known) or 'none'})")
        return {name: o.parse(given[name]) if name in given else o.default
                for name, o in known.items()}

    def renderer_module(self) -> str:
        return self.renderer.partition(":")[0]


def resolve(target: str) -> Callable[..., Any]:
    """The object named ``"module:attribute"``."""
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


def _plugin_modules() -> list[str]:
    import pipeline.methods as package

    builtin = [f"{package.__name__}.{m.name}" for m in pkgutil.iter_modules(package.__path__)]
    extra = [m.strip() for m in os.environ.get("PRT_PLUGINS", "").split(",") if m.strip()]
    return builtin + extra


@cache
def _registry(modules: tuple[str, ...]) -> dict[str, Method]:
    methods: dict[str, Method] = {}
    for module_name in modules:
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise PrtError("PRT_PLUGINS", f"method plug-in {module_name!r} cannot be "
                           f"imported ({exc})") from None
        method = getattr(module, "METHOD", None)
        if not isinstance(method, Method):
            raise PrtError(module.__file__, "a method plug-in must define METHOD = Method(...)")
        if method.name in methods:
            raise PrtError(module.__file__, f"method {method.name!r} is defined twice")
        for folder, add in ((method.schema_dir, add_schema_dir),
                            (method.kernel_dir, add_kernel_dir)):
            if folder is not None:
                add(folder)
        methods[method.name] = method
    return methods


def registry() -> dict[str, Method]:
    """Every registered method by name (plug-ins imported once per process)."""
    return _registry(tuple(_plugin_modules()))


def get_method(name: str) -> Method:
    methods = registry()
    if name not in methods:
        raise PrtError(None, f"unknown method {name!r} (methods: {', '.join(methods)})")
    return methods[name]


def scene_methods(scene: Scene) -> list[Method]:
    """The methods ``scene`` is baked for (its ``methods:``, else the default), each
    checked against the scene."""
    names = scene.methods if scene.methods is not None else DEFAULT_METHODS
    methods = registry()
    unknown = [n for n in names if n not in methods]
    if unknown:
        raise PrtError(scene.path, f"methods: unknown method {unknown[0]!r} (methods: "
                       f"{', '.join(methods)})")
    for name in names:
        check_method_scene(methods[name], scene)
    return [methods[n] for n in names]


def scene_features(scene: Scene) -> dict[str, str]:
    """The features of :data:`FEATURES` that ``scene`` uses, each with the first key
    path that uses it."""
    used: dict[str, str] = {}
    for i, light in enumerate(scene.lights):
        if light.type == "quad" and light.params.get("object"):
            used.setdefault("emitters", f"lights[{i}].object")
    for name, material in scene.materials.items():
        if material.blend is not None:
            used.setdefault("blends", f"materials.{name}.blend")
        if material.bump is not None:
            used.setdefault("bumps", f"materials.{name}.bump")
    return used


def check_method_scene(method: Method, scene: Scene) -> list[str]:
    """Raise PrtError if ``method`` cannot render ``scene``: a light kind, material model
    or scene feature it does not render (naming the methods that do), no light it
    renders, or its own check. Returns the notes to show before baking: those of the
    method's check and materials whose energy conservation cannot be checked."""
    for i, light in enumerate(scene.lights):
        if light.type not in method.lights:
            raise PrtError(scene.path, f"lights[{i}]: method {method.name} does not render "
                           f"{light.type} lights (methods that do: "
                           f"{_methods_with('lights', light.type)})")
    if not scene.lights:
        raise PrtError(scene.path, f"lights: the scene has no light; method {method.name} "
                       f"renders {', '.join(method.lights)} lights")
    for name, material in scene.materials.items():
        if material.model not in method.materials:
            raise PrtError(scene.path, f"materials.{name}: method {method.name} does not "
                           f"render {material.model} materials (methods that do: "
                           f"{_methods_with('materials', material.model)})")
    for feature, where in scene_features(scene).items():
        if feature not in method.features:
            raise PrtError(scene.path, f"{where}: method {method.name} does not render "
                           f"{FEATURES[feature]} (methods that do: "
                           f"{_methods_with('features', feature)})")
    notes = [f"materials.{name}: {material.model} has no bounded albedo (it grows towards "
             "grazing angles), so whether it conserves energy is not checked"
             for name, material in scene.materials.items()
             if specular_albedo_bound(material.model, 1.0) is None]
    if method.check_scene:
        notes += resolve(method.check_scene)(scene) or []
    return notes


def _methods_with(field_name: str, value: str) -> str:
    """The registered methods whose ``field_name`` holds ``value``, listed for a message
    (``none yet`` if none)."""
    found = [m.name for m in registry().values()
             if m.renders and value in getattr(m, field_name)]
    return ", ".join(found) or "none yet"


def scene_notes(scene: Scene, methods: list[Method]) -> list[str]:
    """The notes of :func:`check_method_scene` for each of ``methods``, each once."""
    notes: list[str] = []
    for method in methods:
        notes += [n for n in check_method_scene(method, scene) if n not in notes]
    return notes


def stagefile_fragments() -> tuple[Path, ...]:
    """The stage files of plug-ins that bring their own."""
    return tuple(m.stagefile for m in registry().values() if m.stagefile is not None)


def check_one_environment(scene: Scene, method: str) -> None:
    """PrtError unless ``scene`` has exactly one environment light whose map reads as a
    valid latitude-longitude map (for the methods lit by a map alone; checked before
    anything is baked: a lighting stage would refuse the map only after the geometry
    stage has run)."""
    count = sum(light.type == "environment" for light in scene.lights)
    if count != 1:
        raise PrtError(scene.path, f"lights: method {method} renders exactly one environment "
                       f"light; the scene has {count}")
    read_environment(scene.environment_file())
