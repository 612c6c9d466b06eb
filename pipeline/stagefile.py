"""stages.yaml: the human-written declaration of every stage, validated on load.

Format ``prt-stages/1``::

    format: prt-stages/1
    params:                      # every parameter key with its default; a scene's
      gbuffer.tile: 64           # ``settings`` may override any of them
    stages:
      NAME:
        impl: gbuffer            # registered stage name, or a module path ``pkg.mod[:attr]``
        description: ...
        inputs: [geometry]       # stages whose artifacts it reads
        scene: [camera]          # scene sections it reads (dotted; ``*`` see below)
        params: [gbuffer.tile]   # parameter keys it reads
        kernels: []              # kernels/ files whose source is part of its code version
        output: gbuffer          # schema kind of the artifact it writes
        chunks: none | object | material | {by: tile, size: PARAM}
                | {by: block, size: PARAM, of: PARAM}

Scene sections may hold ``*``: in a stage chunked by object, ``objects.*.X`` is the chunk's
own object and ``materials.*`` its material; in a stage chunked by material (one chunk per
scene material, in the scene's order), ``materials.*`` is the chunk's material; otherwise
``*`` stands for every object or material.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import PrtError

STAGEFILE_FORMAT = "prt-stages/1"
CHUNKINGS = ("none", "object", "material", "tile", "block")


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
    chunking: str
    tile_param: str | None
    count_param: str | None = None


@dataclass(frozen=True)
class StageFile:
    """All stages (in file order) and parameter defaults."""

    path: Path
    params: dict[str, Any]
    stages: dict[str, StageSpec]


def default_stagefile_path() -> Path:
    """stages.yaml from the checkout, else the copy that pyproject.toml packages with
    the code as ``pipeline/project/stages.yaml`` (so that ``pip install --target`` or
    ``--user`` finds it too). Without either, the checkout's path, which load_stagefile
    reports as not found."""
    checkout = Path(__file__).resolve().parent.parent / "stages.yaml"
    if checkout.is_file():
        return checkout
    from importlib.resources import files

    # Through the regular package ``pipeline``: files() of the namespace package
    # pipeline.project is a MultiplexedPath, whose str() is no file name.
    packaged = Path(str(files("pipeline").joinpath("project", "stages.yaml")))
    return packaged if packaged.is_file() else checkout


def load_stagefile(path: str | Path | None = None) -> StageFile:
    """Parse and validate a stage file; raise PrtError naming the file and the key."""
    path = Path(path) if path else default_stagefile_path()
    if not path.is_file():
        raise PrtError(path, "stage file not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise PrtError(path, f"malformed YAML: {str(exc).splitlines()[0]}") from None

    def fail(where: str, problem: str) -> PrtError:
        return PrtError(path, f"{where}: {problem}")

    if not isinstance(doc, dict) or doc.get("format") != STAGEFILE_FORMAT:
        raise fail("format", f"expected {STAGEFILE_FORMAT!r}")
    unknown = sorted(set(doc) - {"format", "params", "stages"})
    if unknown:
        raise fail(unknown[0], "unknown top-level key")
    params = doc.get("params") or {}
    if not isinstance(params, dict):
        raise fail("params", "expected a mapping of parameter defaults")
    stages_doc = doc.get("stages")
    if not isinstance(stages_doc, dict) or not stages_doc:
        raise fail("stages", "expected a non-empty mapping of stages")

    allowed = {"impl", "description", "inputs", "scene", "params", "kernels", "output",
               "chunks"}
    stages: dict[str, StageSpec] = {}
    for name, spec in stages_doc.items():
        where = f"stages.{name}"
        if not isinstance(spec, dict):
            raise fail(where, "expected a mapping")
        extra = sorted(set(spec) - allowed)
        if extra:
            raise fail(where, f"unknown key {extra[0]!r} (allowed: {', '.join(sorted(allowed))})")
        for key in ("impl", "output"):
            if not isinstance(spec.get(key), str):
                raise fail(f"{where}.{key}", "expected a string")
        lists = {}
        for key in ("inputs", "scene", "params", "kernels"):
            value = spec.get(key) or []
            if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                raise fail(f"{where}.{key}", "expected a list of strings")
            lists[key] = tuple(value)
        for key in lists["params"]:
            if key not in params:
                raise fail(f"{where}.params", f"parameter {key!r} has no default in params")
        chunks = spec.get("chunks", "none")
        tile_param = count_param = None
        if isinstance(chunks, dict):
            by = chunks.get("by")
            if not ((by == "tile" and set(chunks) == {"by", "size"})
                    or (by == "block" and set(chunks) == {"by", "size", "of"})):
                raise fail(f"{where}.chunks", "expected {by: tile, size: PARAM} or "
                           "{by: block, size: PARAM, of: PARAM}")
            tile_param, count_param = chunks["size"], chunks.get("of")
            for key in ("size", "of"):
                if key in chunks and chunks[key] not in lists["params"]:
                    raise fail(f"{where}.chunks.{key}", f"{chunks[key]!r} is not among the "
                               "stage's declared params")
            if by == "tile" and "camera" not in lists["scene"]:
                raise fail(f"{where}.chunks", "tile chunking needs the camera scene section")
            chunks = by
        if chunks not in CHUNKINGS:
            raise fail(f"{where}.chunks", f"expected one of {', '.join(CHUNKINGS)}")
        stages[name] = StageSpec(name, spec["impl"], str(spec.get("description", "")),
                                 lists["inputs"], lists["scene"], lists["params"],
                                 lists["kernels"], spec["output"], chunks, tile_param,
                                 count_param)
    for spec in stages.values():
        for dep in spec.inputs:
            if dep not in stages:
                raise fail(f"stages.{spec.name}.inputs", f"unknown stage {dep!r}")
    return StageFile(path, dict(params), stages)
