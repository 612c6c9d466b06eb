"""The method descriptor: what a rendering method plug-in declares (:class:`Method`, its
run-time :class:`Option` s and measured :class:`Component` s), and the scene checks every
method shares. The registry that finds the plug-ins is pipeline/methods/__init__.py.

A method (paper 000's ``d2i``, the ``direct`` baseline, and whatever comes next) is a
module or package that defines ``METHOD = Method(...)``; its own stages (a stage file in
stages.yaml's format), schemas and kernels are found through its descriptor or, for the
built-in methods, in their folders (``pipeline/methods/<name>/``, ``kernels/<name>/``,
``data_schema/<name>/``).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.errors import PrtError
from pipeline.math.brdf import MATERIAL_PARAMETERS

# Every material model (BRDF) of the scene format: what a method renders unless it says.
ALL_MATERIALS = tuple(MATERIAL_PARAMETERS)
# Scene features beyond light kinds and materials that a method renders only when it
# declares them (``Method.features``), each with what it is.
FEATURES = {
    "emitters": "the emitting object of a quad light (its radiance seen by the camera)",
    "blends": "a material blended with another by a texture (materials.NAME.blend)",
    "bumps": "a bump map (materials.NAME.bump)",
}


# The scene edits a method can declare it follows at run time (``Method.edits``), each
# with what it is; pipeline/scene/edits.py applies them, ``prt render`` takes each as an
# option and ``prt view`` shows a control for each.
EDITS = {
    "light": "move a light with a position (point, spot, quad): --move-light",
    "environment": "turn the environment map about its axis: --env-rotate",
    "camera": "move the camera about its look_at point: --camera",
    "gamma": "a glossy material's exponent γ within its gamma_range: --set M.gamma=",
    "specular": "a glossy material's ρs: --set M.specular=",
    "albedo": "a material's diffuse albedo: --set M.albedo=",
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
    (pipeline/evaluation/reference.py LOBES): the method's frame less the frame of ``subtract`` (a
    method sharing its shader for the rest; d2i: its indirect light), or, without
    ``subtract``, the method's frame with the run-time ``options`` (sg: its glossy
    lobes, ``(("component", "glossy"),)``)."""

    transport: str
    subtract: str | None = None
    options: tuple[tuple[str, Any], ...] = ()
    lobe: str = "all"


@dataclass(frozen=True)
class Limit:
    """Where a method's picture breaks down, declared as a check that warns.

    ``name``: a short kebab-case name; ``what``: one sentence for ``prt methods`` (the
    condition, what it does to the picture, the setting that fixes it); ``check``:
    ``"module:function"``, ``function(scene, params, artifacts)`` returns the warning for
    ``scene`` (the cause, the figure measured on it and the setting that fixes it) or
    None. It runs before the bake with ``artifacts`` None (a check that needs the baked
    artifacts returns None then) and at render time with the opened artifacts of the
    method's ``reads`` (by stage name), on the scene as rendered (its run-time size and
    edits applied); ``params``: the stage parameters the scene bakes with. A check warns
    only where the picture changes by more than the references' noise (about 2 %)
    would hide: a warning that changes nothing a user can see is noise."""

    name: str
    what: str
    check: str


@dataclass(frozen=True)
class Method:
    """What a method plug-in declares.

    ``renderer``: ``"module:factory"``; ``factory(scene, artifacts, **options)`` (a
    class, or a function returning an instance) gives a renderer
    (pipeline/render/__init__.py ``Renderer``: ``frame(scene)``, ``edit_mode(kind,
    scene)``), loaded once from ``artifacts`` (the opened artifacts of ``reads``, by
    stage name), that renders edited scenes.
    ``reads``: the stages whose artifacts a frame reads (what ``prt run`` bakes, with
    their upstream; the frame's storage; its cache key), whatever its options;
    ``option_reads``: (OPTION, VALUE, stages) — more stages a frame reads when a run-time
    option has that value (sg: its fitted lobes only where ``normal`` uses them), so
    that a bake models no more than the frame asked for needs (:meth:`reads_for`).
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
    ``check_scene``: ``"module:function"``; ``function(scene, params)`` (``params``: the
    stage parameters the scene bakes with, its settings applied) raises PrtError if the
    method cannot render the scene for another reason (e.g. a material lacks a setting
    it needs); it may return notes (a list of strings), shown before the bake and in
    ``--json`` output.
    ``stagefile``, ``schema_dir``, ``kernel_dir``: a plug-in's own stages, schemas and
    kernels (the built-in methods' live in the project's files).
    ``renders``: False for a plug-in whose renderer is not built yet (it bakes, then
    says so): refusals never name it among the methods that render something.
    ``default``: the method is baked for a scene that names none (``methods:`` absent).
    ``limits``: where its picture breaks down (:class:`Limit`), checked before the bake
    and at render time; each that applies prints a ``warning:`` line.
    ``edits``: the scene edits its renderer follows at run time, without a re-bake (of
    :data:`EDITS`): what ``prt view`` shows controls for (pipeline/view/).
    ``edit_modes``: edit (of ``edits``) -> the ``edit_mode`` kind of its renderer that
    follows a run of that edit alone faster (d2i: a light moved -> ``light``): ``prt
    view`` renders a drag in that mode, the frame on release with ``frame``.
    ``drag_options``: run-time options (NAME, VALUE) that ``prt view`` renders with
    while the user drags (a cheaper budget), the accurate frame on release.
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
    default: bool = False
    limits: tuple[Limit, ...] = ()
    edits: tuple[str, ...] = ()
    edit_modes: dict[str, str] = field(default_factory=dict)
    drag_options: tuple[tuple[str, Any], ...] = ()
    option_reads: tuple[tuple[str, Any, tuple[str, ...]], ...] = ()

    def reads_for(self, options: Mapping[str, Any] | None = None) -> tuple[str, ...]:
        """The stages a frame with run-time ``options`` (parsed values; an option not
        given: its default) reads: ``reads`` and the ``option_reads`` that apply."""
        values = {o.name: o.default for o in self.options} | dict(options or {})
        extra = [stage for name, value, stages in self.option_reads
                 if values.get(name) == value for stage in stages]
        return tuple(dict.fromkeys([*self.reads, *extra]))

    def every_read(self) -> tuple[str, ...]:
        """Every stage a frame of some options reads (``reads`` and all ``option_reads``)."""
        return tuple(dict.fromkeys([*self.reads, *(s for *_, stages in self.option_reads
                                                   for s in stages)]))

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
