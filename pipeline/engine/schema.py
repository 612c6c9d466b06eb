"""Artifact schemas: one versioned YAML file per artifact kind in ``data_schema/``.

A schema declares, for each array, its dimension names, dtype and chunk shape, how a
chunked stage writes it, plus the required attributes and their types. ``write``:

* ``whole`` (default): written at once, by an unchunked stage's one chunk or by the
  stage's ``finalize``;
* ``region``: a fixed full shape (the stage's ``layout``); each chunk writes its block
  in place (pixel tiles, one material's row), zarr chunks aligned with the blocks;
* ``segments``: each chunk writes its own variable-length piece along the first
  dimension (a pixel tile's CSR rows, an object's vertices); readers see the pieces
  concatenated in chunk order. ``offset_by: ARRAY`` marks segment-local indices into
  another segmented array (an object's faces into its vertices): read back, each
  piece is offset by where that array's piece of the same chunk starts.

Chunk entries are integers or symbols: a symbol that names one of the array's own
dimensions means "that whole dimension"; any other symbol (``tile``, ``vertex_chunk``)
is a size the writer supplies. Writers check arrays, pieces and attributes before
writing; readers compare kind and version with :meth:`Schema.check_header`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.searchpath import schema_dirs
from pipeline.yamlfile import load_yaml

WRITES = ("whole", "region", "segments")
_ATTR_TYPES = {"int": int, "float": (int, float), "str": str, "list": list, "dict": dict,
               "bool": bool}


@dataclass(frozen=True)
class ArraySpec:
    """One declared array: dimension names, dtype and symbolic chunk shape."""

    name: str
    dims: tuple[str, ...]
    dtype: np.dtype
    chunks: tuple[int | str, ...]
    description: str
    write: str = "whole"
    offset_by: str | None = None

    def chunk_shape(self, shape: tuple[int, ...], sizes: dict[str, int]) -> tuple[int, ...]:
        """Concrete chunk shape for an array of ``shape`` (each entry clipped to [1, dim])."""
        out = []
        for extent, entry in zip(shape, self.chunks, strict=True):
            if isinstance(entry, int):
                size = entry
            elif entry in self.dims:
                size = shape[self.dims.index(entry)]
            else:
                size = sizes[entry]
            out.append(max(1, min(int(size), int(extent))))
        return tuple(out)


@dataclass(frozen=True)
class Schema:
    """A parsed schema file."""

    kind: str
    version: int
    description: str
    arrays: dict[str, ArraySpec]
    attrs: dict[str, str]
    path: Path

    def check_arrays(self, arrays: dict[str, np.ndarray], attrs: dict[str, Any],
                     where: str) -> None:
        """Raise PrtError unless ``arrays``/``attrs`` conform: same array names, ranks,
        dtypes, consistent sizes along equally named dimensions, required attrs typed."""
        names, declared = set(arrays), set(self.arrays)
        if names != declared:
            extra, missing = sorted(names - declared), sorted(declared - names)
            raise PrtError(where, f"does not match schema {self.kind} v{self.version}: "
                           f"missing arrays {missing}, unexpected arrays {extra}")
        dim_sizes: dict[str, tuple[int, str]] = {}
        for name, spec in self.arrays.items():
            data = arrays[name]
            self.check_array(name, data, where)
            for dim, size in zip(spec.dims, data.shape, strict=True):
                seen = dim_sizes.setdefault(dim, (size, name))
                if seen[0] != size:
                    raise PrtError(where, f"dimension {dim}: {size} in array {name} but "
                                   f"{seen[0]} in array {seen[1]}")
        self.check_attrs(attrs, where)

    def check_array(self, name: str, data: np.ndarray, where: str) -> None:
        """Raise PrtError unless ``data`` (a whole array or a chunk's piece of it) has
        the declared rank and dtype of array ``name``."""
        spec = self.arrays.get(name)
        if spec is None:
            raise PrtError(where, f"array {name!r} is not in schema {self.kind} "
                           f"v{self.version} (arrays: {', '.join(self.arrays)})")
        if data.ndim != len(spec.dims):
            raise PrtError(where, f"array {name}: expected {len(spec.dims)} dimensions "
                           f"{list(spec.dims)}, found shape {data.shape}")
        if data.dtype != spec.dtype:
            raise PrtError(where, f"array {name}: expected dtype {spec.dtype}, "
                           f"found {data.dtype}")

    def check_attrs(self, attrs: dict[str, Any], where: str) -> None:
        """Raise PrtError unless every required attribute is present and typed."""
        for key, type_name in self.attrs.items():
            if key not in attrs:
                raise PrtError(where, f"missing attribute {key!r} required by schema "
                               f"{self.kind} v{self.version}")
            if not isinstance(attrs[key], _ATTR_TYPES[type_name]):
                raise PrtError(where, f"attribute {key!r}: expected {type_name}, found "
                               f"{type(attrs[key]).__name__}")

    def check_header(self, kind: Any, version: Any, where: str) -> None:
        """Raise PrtError unless a stored (kind, version) is this schema's."""
        if kind != self.kind:
            raise PrtError(where, f"artifact kind is {kind!r}, expected {self.kind!r}")
        if version != self.version:
            raise PrtError(where, f"artifact has schema {kind} version {version}, this "
                           f"prt reads version {self.version}; re-bake it with "
                           "`prt run --force STAGE` or `prt clean`")


def load_schema(kind: str) -> Schema:
    """Parse and check ``<schema dir>/<kind>.yaml`` (first folder that has it; see
    pipeline/searchpath.py)."""
    return _load_schema(kind, tuple(schema_dirs()))


@cache
def _load_schema(kind: str, dirs: tuple[Path, ...]) -> Schema:
    candidates = [d / f"{kind}.yaml" for d in dirs]
    path = next((c for c in candidates if c.is_file()), None)
    if path is None:
        raise PrtError(candidates[0], f"no schema for artifact kind {kind!r}")
    doc = load_yaml(path)
    try:
        arrays = {
            name: ArraySpec(name, tuple(spec["dims"]), np.dtype(spec["dtype"]),
                            tuple(spec["chunks"]), spec.get("description", ""),
                            spec.get("write", "whole"), spec.get("offset_by"))
            for name, spec in doc["arrays"].items()
        }
        for spec in arrays.values():
            if len(spec.chunks) != len(spec.dims):
                raise ValueError(f"array {spec.name}: chunks and dims differ in length")
            if spec.write not in WRITES:
                raise ValueError(f"array {spec.name}: write {spec.write!r}, expected one "
                                 f"of {', '.join(WRITES)}")
            if spec.offset_by is not None and (
                    spec.write != "segments"
                    or arrays.get(spec.offset_by, spec).write != "segments"):
                raise ValueError(f"array {spec.name}: offset_by needs two segmented arrays")
        attrs = {k: v for k, v in (doc.get("attrs") or {}).items()}
        unknown = sorted(set(attrs.values()) - set(_ATTR_TYPES))
        if unknown:
            raise ValueError(f"unknown attribute type {unknown[0]!r}")
        if doc["kind"] != kind:
            raise ValueError(f"kind is {doc['kind']!r}, file name says {kind!r}")
        return Schema(doc["kind"], int(doc["version"]), doc.get("description", ""), arrays,
                      attrs, path)
    except (KeyError, TypeError, ValueError) as exc:
        raise PrtError(path, f"invalid schema file: {exc}") from None
