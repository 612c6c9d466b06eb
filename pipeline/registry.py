"""The method registry: every method plug-in defines ``METHOD = Method(...)``
(pipeline/method.py); the core (cli, job, evaluation) reads them through
:func:`registry` and names none. Plug-ins are found

* in the package ``pipeline.methods`` (every module or folder there is a plug-in), and
* in the modules named by the environment variable ``PRT_PLUGINS`` (comma-separated
  importable module names: a method kept outside the project, e.g. under ``tests/``).

A scene lists the methods it is baked for under ``methods:`` (default: the methods whose
descriptor says ``default=True``); ``prt run`` bakes only what those read.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

from pipeline import methods
from pipeline.engine.planning import stage_params
from pipeline.engine.stagefile import StageFile, default_stagefile_path, load_stagefile
from pipeline.errors import PrtError
from pipeline.math.brdf import specular_albedo_bound
from pipeline.method import EDITS, FEATURES, Method, resolve
from pipeline.scene.model import Scene
from pipeline.searchpath import add_kernel_dir, add_schema_dir


def _plugin_modules() -> list[str]:
    builtin = [f"{methods.__name__}.{m.name}" for m in pkgutil.iter_modules(methods.__path__)]
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
        check_descriptor(method, module.__file__)
        methods[method.name] = method
    return methods


def check_descriptor(method: Method, where: Any) -> None:
    """PrtError (naming ``where``, the plug-in's file) for a run-time edit outside
    :data:`EDITS`, or an ``option_reads`` entry naming an option the method does not
    declare or a value that option does not take (its stages would never be baked)."""
    unknown = [e for e in (*method.edits, *method.edit_modes) if e not in EDITS]
    if unknown:
        raise PrtError(where, f"method {method.name!r} declares an unknown run-time edit "
                       f"{unknown[0]!r} (edits: {', '.join(EDITS)})")
    options = {o.name: o for o in method.options}
    for name, value, _ in method.option_reads:
        option = options.get(name)
        if option is None:
            raise PrtError(where, f"method {method.name!r}: option_reads names option "
                           f"{name!r}, which it does not declare (options: "
                           f"{', '.join(options) or 'none'})")
        if option.choices and value not in option.choices:
            raise PrtError(where, f"method {method.name!r}: option_reads gives {name}="
                           f"{value!r}, not one of {', '.join(option.choices)}")


def registry() -> dict[str, Method]:
    """Every registered method by name (plug-ins imported once per process)."""
    return _registry(tuple(_plugin_modules()))


def default_methods() -> tuple[str, ...]:
    """The methods baked for a scene that names none (their descriptors' ``default``)."""
    return tuple(name for name, m in registry().items() if m.default)


def get_method(name: str) -> Method:
    methods = registry()
    if name not in methods:
        raise PrtError(None, f"unknown method {name!r} (methods: {', '.join(methods)})")
    return methods[name]


def scene_methods(scene: Scene) -> list[Method]:
    """The methods ``scene`` is baked for (its ``methods:``, else the default), each
    checked against the scene."""
    names = scene.methods if scene.methods is not None else default_methods()
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
        params = stage_params(_project_stagefile(), scene)
        notes += resolve(method.check_scene)(scene, params) or []
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


def limit_warnings(method: Method, scene: Scene, artifacts: Mapping[str, Any] | None = None
                   ) -> list[str]:
    """The warnings of ``method``'s limits (pipeline/method.py ``Limit``) on ``scene``:
    before the bake (``artifacts`` None) or at render time (the opened artifacts its
    frames read), each as ``method NAME, LIMIT: text``."""
    params = stage_params(_project_stagefile(), scene)
    found = ((limit, resolve(limit.check)(scene, params, artifacts)) for limit in method.limits)
    return [f"method {method.name}, {limit.name}: {text}" for limit, text in found if text]


def _project_stagefile() -> StageFile:
    """The project's stage graph merged with the plug-ins' (what ``check_scene`` hooks
    read their parameters from), parsed once per version of its files: ≈ 28 ms a parse,
    and every command checks each of a scene's methods."""
    files = (default_stagefile_path(), *stagefile_fragments())
    return _parsed_stagefile(tuple((f, f.stat().st_mtime_ns) for f in files))


@cache
def _parsed_stagefile(files: tuple[tuple[Path, int], ...]) -> StageFile:
    return load_stagefile(files[0][0], tuple(f for f, _ in files[1:]))


def stagefile_fragments() -> tuple[Path, ...]:
    """The stage files of plug-ins that bring their own."""
    return tuple(m.stagefile for m in registry().values() if m.stagefile is not None)
