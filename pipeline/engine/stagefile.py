"""stages.yaml: the human-written declaration of every stage, validated on load.

Format ``prt-stages/2``::

    format: prt-stages/2
    params:                      # every parameter key with its default; a scene's
      gbuffer.tile: 64           # ``settings`` may override any of them
    limits:                      # [least, most] a scene's setting may give a number (or
      gbuffer.tile: [1, 4096]    # each number of a list); numbers without limits must
                                 # still be finite and not negative
    stages:
      NAME:                      # shared stages have plain names; a method's stages are
                                 # namespaced by it: ``d2i.transfer``
        impl: gbuffer            # registered stage name, or a module path ``pkg.mod[:attr]``
        description: ...
        inputs: [geometry]       # stages whose artifacts it reads
        chunk_inputs: []         # inputs of which each chunk reads only the chunks of its
                                 # own object or materials, or (an input chunked as
                                 # this stage is) its twin chunk, or (an input chunked
                                 # by the tiles a tile_material stage splits) its
                                 # parent tile: keyed on just those
        scene: [camera]          # scene sections it reads (dotted; ``*`` see below)
        params: [gbuffer.tile]   # parameter keys it reads
        kernels: []              # kernel files it builds beyond those its modules name
        output: gbuffer          # schema kind of the artifact it writes
        chunks: none | object | material
              | {by: tile, size: PARAM[, materials_from: STAGE]}   # pixel tiles
              | {by: tile_material, size: PARAM, materials_from: STAGE[,
                 skip_models: [MODEL, ...]]}      # a pixel tile's pixels of one material
              | {by: block, size: PARAM, of: PARAM}                # [0, count) in blocks
              | {by: texel_tile, size: PARAM, of: STAGE}           # tiles of UV atlases
              | {by: vertex_batch, size: PARAM, of: STAGE}         # per-object vertex runs

Chunkings and what they read are in pipeline/engine/chunking.py. Scene sections may hold
``*``: ``objects.*.X`` binds to the chunk's object where it has one and ``materials.*``
to the chunk's materials (its own material, its object's, or those it sees); otherwise
``*`` stands for every object or material.

Method plug-ins may bring their own stage file in the same format
(``Method.stagefile``); :func:`load_stagefile` merges it with the project's, and a
parameter or stage declared twice is an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from pipeline.errors import PrtError
from pipeline.yamlfile import load_yaml

STAGEFILE_FORMAT = "prt-stages/2"
FIXED_CHUNKINGS = ("none", "object", "material")


@dataclass(frozen=True)
class ChunkSpec:
    """How a stage is chunked: ``by`` (a chunking of pipeline/engine/chunking.py), ``size`` and
    ``count`` (parameter names), ``of`` (the upstream stage whose attributes lay the
    chunks out), ``materials_from`` (the stage whose ``material_id`` tells a pixel
    tile which materials it sees) and ``skip_models`` (material models a
    ``tile_material`` stage makes no chunks for)."""

    by: str = "none"
    size: str | None = None
    count: str | None = None
    of: str | None = None
    materials_from: str | None = None
    skip_models: tuple[str, ...] = ()

    def parent(self) -> ChunkSpec | None:
        """The chunking whose chunks this one's split (a ``tile_material`` chunk's
        pixel tile, its coordinate ``tile``), None if it splits none."""
        if self.by != "tile_material":
            return None
        return ChunkSpec("tile", size=self.size, materials_from=self.materials_from)


@dataclass(frozen=True)
class StageSpec:
    """One declared stage."""

    name: str
    impl: str
    description: str
    inputs: tuple[str, ...]
    scene: tuple[str, ...]
    params: tuple[str, ...]
    kernels: tuple[str, ...]
    output: str
    chunks: ChunkSpec = field(default_factory=ChunkSpec)
    chunk_inputs: tuple[str, ...] = ()

    @property
    def chunking(self) -> str:
        return self.chunks.by


@dataclass(frozen=True)
class StageFile:
    """All stages (in file order) and parameter defaults; ``path`` is the main file."""

    path: Path
    params: dict[str, Any]
    stages: dict[str, StageSpec]
    limits: dict[str, tuple[float, float]] = field(default_factory=dict)


# ------------------------------------------------------------------- the file's model

_STRICT = ConfigDict(extra="forbid", strict=True)


class _Tile(BaseModel):
    model_config = _STRICT
    by: Literal["tile"]
    size: str
    materials_from: str | None = None


class _TileMaterial(BaseModel):
    model_config = _STRICT
    by: Literal["tile_material"]
    size: str
    materials_from: str
    skip_models: list[str] = []


class _Block(BaseModel):
    model_config = _STRICT
    by: Literal["block"]
    size: str
    of: str


class _FromUpstream(BaseModel):
    model_config = _STRICT
    by: Literal["texel_tile", "vertex_batch"]
    size: str
    of: str


_Chunks = Literal["none", "object", "material"] | Annotated[
    _Tile | _TileMaterial | _Block | _FromUpstream, Field(discriminator="by")]


class _Stage(BaseModel):
    model_config = _STRICT
    impl: str
    description: str = ""
    inputs: list[str] = []
    chunk_inputs: list[str] = []
    scene: list[str] = []
    params: list[str] = []
    kernels: list[str] = []
    output: str
    chunks: _Chunks = "none"


class _File(BaseModel):
    model_config = ConfigDict(extra="forbid")
    format: Literal["prt-stages/2"]
    params: dict[str, Any] = {}
    limits: dict[str, tuple[float, float]] = {}
    stages: dict[str, _Stage] = {}


def _problem(exc: ValidationError) -> str:
    """The first pydantic error as ``key.path: problem``."""
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"] if not str(p).startswith(("_", "function")))
    kind = err["type"]
    if kind == "extra_forbidden":
        return f"{where}: unknown key"
    if kind == "missing":
        return f"{where}: required key missing"
    if kind in ("literal_error", "union_tag_invalid"):
        return f"{where}: {err['msg'].lower()}"
    return f"{where}: {err['msg'].lower()}"


def _read(path: Path) -> _File:
    if not path.is_file():
        raise PrtError(path, "stage file not found")
    doc = load_yaml(path)
    if not isinstance(doc, dict) or doc.get("format") != STAGEFILE_FORMAT:
        raise PrtError(path, f"format: expected {STAGEFILE_FORMAT!r}")
    try:
        return _File.model_validate(doc)
    except ValidationError as exc:
        raise PrtError(path, _problem(exc)) from None


# ----------------------------------------------------------------------------- loading


def default_stagefile_path() -> Path:
    """stages.yaml from the checkout, else the copy that pyproject.toml packages with
    the code as ``pipeline/project/stages.yaml`` (so that ``pip install --target`` or
    ``--user`` finds it too). Without either, the checkout's path, which load_stagefile
    reports as not found."""
    checkout = Path(__file__).resolve().parents[2] / "stages.yaml"
    if checkout.is_file():
        return checkout
    from importlib.resources import files

    # Through the regular package ``pipeline``: files() of the namespace package
    # pipeline.project is a MultiplexedPath, whose str() is no file name.
    packaged = Path(str(files("pipeline").joinpath("project", "stages.yaml")))
    return packaged if packaged.is_file() else checkout


def _chunk_spec(chunks: Any) -> ChunkSpec:
    if isinstance(chunks, str):
        return ChunkSpec(chunks)
    if isinstance(chunks, _Block):
        return ChunkSpec("block", size=chunks.size, count=chunks.of)
    if isinstance(chunks, _Tile):
        return ChunkSpec("tile", size=chunks.size, materials_from=chunks.materials_from)
    if isinstance(chunks, _TileMaterial):
        return ChunkSpec("tile_material", size=chunks.size,
                         materials_from=chunks.materials_from,
                         skip_models=tuple(chunks.skip_models))
    return ChunkSpec(chunks.by, size=chunks.size, of=chunks.of)


def load_stagefile(path: str | Path | None = None,
                   fragments: tuple[Path, ...] = ()) -> StageFile:
    """Parse and validate a stage file (default: the project's) merged with plug-ins'
    ``fragments``; raise PrtError naming the file and the key."""
    path = Path(path) if path else default_stagefile_path()
    params: dict[str, Any] = {}
    limits: dict[str, tuple[float, float]] = {}
    stages: dict[str, StageSpec] = {}
    owner: dict[str, Path] = {}
    for file in (path, *fragments):
        doc = _read(file)
        for key, value in doc.params.items():
            if key in params:
                raise PrtError(file, f"params.{key}: already declared in {owner[key]}")
            params[key], owner[key] = value, file
        for key, (low, high) in doc.limits.items():
            if key not in params or key in limits or not low <= high:
                raise PrtError(file, f"limits.{key}: " + (
                    "not a declared parameter" if key not in params else
                    "already limited" if key in limits else f"{low} > {high}"))
            limits[key] = (low, high)
        for name, s in doc.stages.items():
            if name in stages:
                raise PrtError(file, f"stages.{name}: already declared in {owner[name]}")
            spec = StageSpec(name, s.impl, s.description, tuple(s.inputs), tuple(s.scene),
                             tuple(s.params), tuple(s.kernels), s.output,
                             _chunk_spec(s.chunks), tuple(s.chunk_inputs))
            stages[name], owner[name] = spec, file
    for spec in stages.values():
        _check(spec, params, stages, owner[spec.name])
    return StageFile(path, params, stages, limits)


def _check(spec: StageSpec, params: dict[str, Any], stages: dict[str, StageSpec],
           file: Path) -> None:
    """Cross-references of one stage: its params have defaults, its inputs exist, its
    chunking names declared params and read stages."""
    where = f"stages.{spec.name}"
    for key in spec.params:
        if key not in params:
            raise PrtError(file, f"{where}.params: parameter {key!r} has no default in params")
    for dep in spec.inputs:
        if dep not in stages:
            raise PrtError(file, f"{where}.inputs: unknown stage {dep!r}")
    for dep in spec.chunk_inputs:
        if dep not in spec.inputs:
            raise PrtError(file, f"{where}.chunk_inputs: {dep!r} is not among the stage's "
                           "inputs")
        if stages[dep].chunks.by not in ("object", "material") \
                and stages[dep].chunks not in (spec.chunks, spec.chunks.parent()):
            raise PrtError(file, f"{where}.chunk_inputs: {dep!r} is not chunked by object "
                           "or material, nor as this stage is, nor by the tiles it splits")
    c = spec.chunks
    for key, value in (("size", c.size), ("of", c.count)):
        if value is not None and value not in spec.params:
            raise PrtError(file, f"{where}.chunks.{key}: {value!r} is not among the stage's "
                           "declared params")
    for key, value in (("of", c.of), ("materials_from", c.materials_from)):
        if value is not None and value not in spec.inputs:
            raise PrtError(file, f"{where}.chunks.{key}: {value!r} is not among the stage's "
                           "inputs")
    if c.by in ("tile", "tile_material") and "camera" not in spec.scene:
        raise PrtError(file, f"{where}.chunks: tile chunking needs the camera scene section")
