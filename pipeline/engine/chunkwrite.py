"""Chunked artifacts written in place: every chunk writes its own part of the final zarr
group, and the artifact is complete only when every chunk is recorded.

The life of a stage's artifact ``<stage>.zarr`` while the stage runs:

1. :func:`begin` (the driver) keeps the group when its layout (the full shapes of its
   ``region`` arrays, the chunk sizes) is unchanged, else makes it anew with every
   ``region`` array at full shape; it marks the record ``complete: false`` with the
   planned key and chunk order. From here until :func:`finish`, readers refuse the
   artifact (``open_artifact``), and ``prt status`` says it is incomplete.
2. :func:`write_chunk` (a worker) writes the chunk's arrays (pipeline/engine/schema.py
   ``write``): its block of each ``region`` array (zarr chunks are aligned with the
   blocks, so parallel writers never share a zarr chunk), its own piece of each
   ``segments`` array (a zarr array ``<array>/<chunk>``), the ``whole`` arrays of an
   unchunked stage; then it records the chunk (key, digest, seconds, small metadata)
   in a marker file ``.chunks/<stage>/<chunk>.json``, written by rename. A chunk killed
   half-way has no marker and is written again, in the same places: writes are
   idempotent.
3. :func:`finish` (the driver) drops pieces of chunks no longer planned, writes the
   arrays and attributes the stage's ``finalize`` derives from the chunks' metadata,
   and marks the record complete with the artifact's digest.

A run killed at any moment leaves every other artifact valid, and this one incomplete;
the next run resumes it, re-running only the chunks without a current marker. There is
one copy of the data on disk: no per-chunk cache beside the artifact.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.engine.schema import Schema
from pipeline.engine.store import RECORD_FORMAT, Workdir, compressors, read_record
from pipeline.errors import PrtError


@dataclass(frozen=True)
class Block:
    """A chunk's block of a ``region`` array: ``data`` placed at index ``start`` (one
    entry per leading dimension it is offset along; the rest start at 0)."""

    start: tuple[int, ...]
    data: np.ndarray


def segment_name(chunk_id: str) -> str:
    """The zarr array name of a chunk's piece of a segmented array."""
    return chunk_id.replace("/", "~")


def _zarr_chunks(schema: Schema, name: str, shape: tuple[int, ...],
                 sizes: dict[str, int]) -> tuple[int, ...]:
    return schema.arrays[name].chunk_shape(shape, sizes) if shape else (1,)


def begin(workdir: Workdir, path: Path, schema: Schema, record: dict[str, Any],
          shapes: dict[str, tuple[int, ...]], sizes: dict[str, int]) -> bool:
    """Open the artifact for writing (see the module docstring, step 1). ``shapes``
    holds the full shape of every ``region`` array; ``record`` the planned key and
    ``chunks`` (the chunk ids in order). True if the existing group (and so the chunks
    already written into it) was kept."""
    import zarr

    regions = [n for n, s in schema.arrays.items() if s.write == "region"]
    missing = sorted(set(regions) - set(shapes))
    if missing:
        raise PrtError(path, f"stage layout gives no shape for region array {missing[0]!r}")
    layout = layout_record(schema, shapes, sizes)
    old = _record_or_none(path)
    keep = old is not None and old.get("layout") == layout
    if not keep:
        _remove(workdir, path)
        group = zarr.open_group(store=str(path), mode="w", zarr_format=3)
        for name in regions:
            spec = schema.arrays[name]
            group.create_array(name, shape=shapes[name], dtype=spec.dtype,
                               compressors=compressors(),
                               chunks=_zarr_chunks(schema, name, shapes[name], sizes),
                               dimension_names=spec.dims, fill_value=0)
        for name, spec in schema.arrays.items():
            if spec.write == "segments":
                group.create_group(name)
    header = {"format": RECORD_FORMAT, "kind": schema.kind, "schema_version": schema.version}
    _set_record(path, {**header, **record, "layout": layout, "complete": False})
    return keep


def layout_record(schema: Schema, shapes: dict[str, tuple[int, ...]],
                  sizes: dict[str, int]) -> dict[str, Any]:
    """The layout an artifact's record keeps (its region arrays' shapes, the chunk
    sizes, the schema version): chunks already written are kept only while it holds."""
    regions = [n for n, s in schema.arrays.items() if s.write == "region"]
    return {"shapes": {n: list(shapes[n]) for n in regions if n in shapes},
            "sizes": dict(sorted(sizes.items())), "schema_version": schema.version}


def write_chunk(path: Path, schema: Schema, chunk_id: str,
                arrays: dict[str, np.ndarray | Block], sizes: dict[str, int]) -> None:
    """Write one chunk's arrays into the artifact being built (step 2, data only)."""
    import zarr

    group = zarr.open_group(store=str(path), mode="r+", zarr_format=3)
    for name, value in arrays.items():
        data = value.data if isinstance(value, Block) else np.ascontiguousarray(value)
        schema.check_array(name, data, f"{path} (chunk {chunk_id})")
        spec = schema.arrays[name]
        if spec.write == "region":
            if not isinstance(value, Block):
                raise PrtError(path, f"array {name} is written by region: chunk {chunk_id} "
                               "must return a Block")
            target = _begun(group, name, path, schema)
            index = tuple(slice(s, s + n) for s, n in
                          zip(value.start, data.shape[:len(value.start)], strict=True))
            target[index] = data
        elif spec.write == "segments":
            _write_whole(_begun(group, name, path, schema), segment_name(chunk_id), data,
                         spec.dims, _zarr_chunks(schema, name, data.shape, sizes))
        else:
            _write_whole(group, name, data, spec.dims,
                         _zarr_chunks(schema, name, data.shape, sizes))


def _begun(group: Any, name: str, path: Path, schema: Schema) -> Any:
    """Array or segment group ``name`` of the artifact begun by :func:`begin`; a one-line
    refusal if it lacks it (begun under a schema of the same version with other arrays)."""
    try:
        return group[name]
    except KeyError:
        raise PrtError(path, f"has no array {name!r} of schema {schema.kind} "
                       f"v{schema.version}: it was begun by a prt whose schema had the same "
                       "version but other arrays; re-bake the stage with "
                       "`prt run --force STAGE`") from None


def _write_whole(group: Any, name: str, data: np.ndarray, dims: tuple[str, ...],
                 chunks: tuple[int, ...]) -> None:
    arr = group.create_array(name, shape=data.shape, dtype=data.dtype, chunks=chunks,
                             compressors=compressors(),
                             dimension_names=dims, fill_value=0, overwrite=True)
    if data.size:
        arr[...] = data


def record_chunk(marker: Path, entry: dict[str, Any]) -> None:
    """Record a written chunk (step 2, last): its marker file, replaced atomically."""
    marker.parent.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_name(f".{marker.name}.{uuid.uuid4().hex}")
    tmp.write_text(json.dumps(entry))
    os.replace(tmp, marker)


def read_marker(marker: Path) -> dict[str, Any] | None:
    """A chunk's marker, or None if absent or unreadable (then the chunk runs again)."""
    try:
        return json.loads(marker.read_text())
    except (OSError, ValueError):
        return None


def finish(path: Path, schema: Schema, chunk_ids: list[str], arrays: dict[str, np.ndarray],
           attrs: dict[str, Any], record: dict[str, Any], sizes: dict[str, int]) -> None:
    """Complete the artifact (step 3): drop stale segment pieces, write the ``whole``
    arrays ``finalize`` made, check the attributes and mark the record complete."""
    import zarr

    schema.check_attrs(attrs, str(path))
    group = zarr.open_group(store=str(path), mode="r+", zarr_format=3)
    wanted = {segment_name(c) for c in chunk_ids}
    for name, spec in schema.arrays.items():
        if spec.write == "segments":
            for piece, _ in list(group[name].arrays()):
                if piece not in wanted:
                    del group[name][piece]
    for name, data in arrays.items():
        schema.check_array(name, data, str(path))
        _write_whole(group, name, np.ascontiguousarray(data), schema.arrays[name].dims,
                     _zarr_chunks(schema, name, data.shape, sizes))
    present = {n for n, _ in group.arrays()} | {n for n, _ in group.groups()}
    absent = sorted(set(schema.arrays) - present)
    if absent:
        raise PrtError(path, f"stage wrote no array {absent[0]!r} of schema {schema.kind}")
    old = _record_or_none(path) or {}
    group.attrs.update(attrs)
    _set_record(path, {**old, **record, "complete": True})


def restore_record(path: Path, record: dict[str, Any]) -> None:
    """Put back the record :func:`begin` replaced, when the run wrote nothing after it."""
    _set_record(path, record)


def _record_or_none(path: Path) -> dict[str, Any] | None:
    try:
        return read_record(path)
    except PrtError:
        return None


def _set_record(path: Path, record: dict[str, Any]) -> None:
    """Replace the group's ``prt`` record by rewriting zarr.json atomically."""
    meta = path / "zarr.json"
    doc = json.loads(meta.read_text())
    doc.setdefault("attributes", {})["prt"] = record
    tmp = path / f".zarr.json.{uuid.uuid4().hex}"
    tmp.write_text(json.dumps(doc, indent=2, allow_nan=False))
    os.replace(tmp, meta)


def _remove(workdir: Workdir, path: Path) -> None:
    if path.exists():
        trash = workdir.tmp / f"old-{uuid.uuid4().hex}"
        os.rename(path, trash)
        shutil.rmtree(trash, ignore_errors=True)
