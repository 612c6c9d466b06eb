"""Zarr artifact storage: work directories, atomic writes, provenance and checked reads.

Layout of a work directory (default ``./.prt/<scene name>/``)::

    <stage>.zarr/            the stage's artifact: a zarr v3 group conforming to its schema,
                             written chunk by chunk in place (pipeline/engine/chunkwrite.py)
    .chunks/<stage>/<chunk>.json  the record of each chunk written (key, digest, seconds)
    views/<W>x<H>/           the camera-dependent stages' artifacts and chunk records
                             (same layout) of the scene resized at run time to W × H
                             (``--size``); the stages that do not read the camera
                             (geometry, brdf_basis) are shared with the file's own size
    views/env-<map>/         likewise the environment-dependent stages' of a scene lit
                             at run time by another map (``--env``); a stage that
                             depends on both goes under views/<W>x<H>+env-<map>/
    .tmp/                    whole writes in progress (references), renamed into place
    .lock                    held by the one run that may write here

Every group carries a provenance record in its attributes under ``prt`` (format
:data:`RECORD_FORMAT`): kind, schema version, stage, key, the parts the key was made of,
seconds spent and software versions. :func:`read_record` reads it from ``zarr.json``
without opening arrays, so freshness checks stay cheap.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import json
import os
import shutil
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.engine.schema import Schema, load_schema
from pipeline.errors import PrtError

RECORD_FORMAT = 1


class Workdir:
    """A work directory holding one scene's artifacts.

    ``views``: (name, stages) pairs, e.g. (``"64x48"``, the camera-dependent stages) for
    a scene resized at run time (:attr:`pipeline.scene.Scene.view`) or (``"env-NAME"``,
    the environment-dependent stages) for one lit by another map
    (:attr:`pipeline.scene.Scene.environment_view`). A stage in some of them keeps its
    artifact and chunk records under ``views/<their names joined by +>/``: previews at
    other sizes or under other maps coexist with the file's own bake in one work
    directory, sharing what they do not change, under one lock."""

    def __init__(self, root: str | Path,
                 views: Iterable[tuple[str, Iterable[str]]] = ()) -> None:
        self.root = Path(root).absolute()
        self.views = tuple((name, frozenset(stages)) for name, stages in views)

    def folder(self, stage: str) -> Path:
        """Where ``stage``'s artifact and chunk records live."""
        names = [name for name, stages in self.views if stage in stages]
        return self.root / "views" / "+".join(names) if names else self.root

    def artifact(self, name: str) -> Path:
        return self.folder(name) / f"{name}.zarr"

    def marker(self, stage: str, chunk: str) -> Path:
        """The record of one written chunk (a ``/`` in a chunk id becomes ``~``)."""
        return self.markers(stage) / f"{chunk.replace('/', '~')}.json"

    def markers(self, stage: str) -> Path:
        return self.folder(stage) / ".chunks" / stage

    @property
    def tmp(self) -> Path:
        return self.root / ".tmp"

    def ensure_writable(self) -> None:
        """Create the folder (and .tmp) or raise PrtError saying why it cannot be used."""
        try:
            self.tmp.mkdir(parents=True, exist_ok=True)
            probe = self.tmp / f"probe-{uuid.uuid4().hex}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise PrtError(self.root, f"work directory is not writable ({exc.strerror})") \
                from None

    def writable(self) -> bool:
        """Whether this process can write here (see :meth:`ensure_writable`)."""
        try:
            self.ensure_writable()
        except PrtError:
            return False
        return True

    def in_use(self) -> bool:
        """Whether another process holds this work directory's lock (a run writing
        here now); False where this process holds it or nothing can be read."""
        if _HELD.get(self.root):
            return False
        try:
            with open(self.root / ".lock", "rb") as handle:
                fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
                fcntl.flock(handle, fcntl.LOCK_UN)
        except BlockingIOError:
            return True
        except OSError:
            return False
        return False

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold an exclusive lock for a run; fail clearly if another run holds it."""
        self.ensure_writable()
        with open(self.root / ".lock", "a+") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise PrtError(self.root, "another prt run is using this work directory") \
                    from None
            # A run killed earlier may have left half-written temporaries; nothing else
            # can be writing now, so they are safe to drop.
            for leftover in self.tmp.iterdir():
                shutil.rmtree(leftover, ignore_errors=True)
            _HELD[self.root] = _HELD.get(self.root, 0) + 1
            try:
                yield
            finally:
                _HELD[self.root] -= 1
                fcntl.flock(handle, fcntl.LOCK_UN)


_HELD: dict[Path, int] = {}  # the work directories whose lock this process holds


def software_versions() -> dict[str, str]:
    """Versions of the libraries whose behaviour shapes artifact contents."""
    import platform
    from importlib import metadata

    import zarr

    import pipeline

    versions = {"python": platform.python_version(), "numpy": np.__version__,
                "zarr": zarr.__version__, "prt": pipeline.__version__}
    for name in ("trimesh", "embreex", "scipy"):  # from their metadata: importing
        with contextlib.suppress(metadata.PackageNotFoundError):  # trimesh takes 0.7 s
            versions[name] = metadata.version(name)
    return versions


def compressors() -> list[Any]:
    """The codecs of every stored array: zstd with its frame checksum on, so that a
    chunk file changed on disk (a flipped byte, a truncated copy) fails to decode and
    is reported (``Artifact.read`` names the chunk), instead of reading as numbers."""
    from zarr.codecs import ZstdCodec

    return [ZstdCodec(level=0, checksum=True)]


def write_group(workdir: Workdir, path: Path, arrays: dict[str, np.ndarray],
                attrs: dict[str, Any], chunks: dict[str, tuple[int, ...]],
                dims: dict[str, tuple[str, ...]]) -> None:
    """Write a zarr v3 group to a temporary folder, then move it onto ``path``.

    The previous group at ``path`` stays valid until the new one is complete; a run
    killed in between leaves either the old group, the new one, or none (never a partial
    one), and a missing group is simply rebuilt by the next run.
    """
    import zarr

    tmp = workdir.tmp / f"{path.name}-{uuid.uuid4().hex}"
    group = zarr.open_group(store=str(tmp), mode="w", zarr_format=3)
    for name, data in arrays.items():
        data = np.ascontiguousarray(data)
        arr = group.create_array(name, shape=data.shape, dtype=data.dtype,
                                 compressors=compressors(),
                                 chunks=chunks.get(name, tuple(max(1, n) for n in data.shape)
                                                   or (1,)),
                                 dimension_names=dims.get(name), fill_value=0)
        if data.size:
            arr[...] = data
    group.attrs.update(attrs)
    _replace_dir(tmp, path, workdir.tmp)


def _replace_dir(src: Path, dst: Path, trash_root: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        trash = trash_root / f"old-{uuid.uuid4().hex}"
        os.rename(dst, trash)
        os.rename(src, dst)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.rename(src, dst)


def write_artifact(workdir: Workdir, path: Path, schema: Schema, arrays: dict[str, np.ndarray],
                   attrs: dict[str, Any], record: dict[str, Any],
                   sizes: dict[str, int]) -> None:
    """Check ``arrays``/``attrs`` against ``schema`` and write them with ``record``."""
    schema.check_arrays(arrays, attrs, str(path))
    chunks = {n: s.chunk_shape(arrays[n].shape, sizes) for n, s in schema.arrays.items()}
    dims = {n: s.dims for n, s in schema.arrays.items()}
    header = {"format": RECORD_FORMAT, "kind": schema.kind, "schema_version": schema.version}
    write_group(workdir, path, arrays, {**attrs, "prt": {**header, **record}}, chunks, dims)


def read_record(path: Path) -> dict[str, Any] | None:
    """The ``prt`` provenance record of a group, or None if the group is absent.

    Raises PrtError if ``zarr.json`` exists but cannot be parsed."""
    meta = path / "zarr.json"
    try:
        doc = json.loads(meta.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise PrtError(meta, f"unreadable artifact metadata ({exc})") from None
    record = doc.get("attributes", {}).get("prt")
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT:
        raise PrtError(path, f"no prt provenance record of format {RECORD_FORMAT}")
    return record


class Artifact:
    """A read-only zarr group: checked header, lazily readable arrays. A segmented array
    (pipeline/engine/schema.py: one piece per chunk, a zarr group of arrays) reads as the
    concatenation of its pieces in the record's chunk order."""

    def __init__(self, path: Path, group: Any, record: dict[str, Any]) -> None:
        self.path = path
        self.group = group
        self.record = record

    @property
    def attrs(self) -> dict[str, Any]:
        return {k: v for k, v in self.group.attrs.items() if k != "prt"}

    @property
    def names(self) -> list[str]:
        return sorted([name for name, _ in self.group.arrays()]
                      + [name for name, _ in self.group.groups()])

    def array(self, name: str) -> Any:
        """The zarr array (lazy), or for a segmented array its first piece; raise
        PrtError if absent."""
        node = self._node(name)
        return node if not self.is_segmented(name) else next(iter(self.pieces(name)), node)

    def _node(self, name: str) -> Any:
        try:
            return self.group[name]
        except KeyError:
            raise PrtError(self.path, f"has no array {name!r}") from None

    def is_segmented(self, name: str) -> bool:
        import zarr

        return isinstance(self._node(name), zarr.Group)

    def pieces(self, name: str) -> list[Any]:
        """A segmented array's pieces (zarr arrays) in chunk order."""
        node = self._node(name)
        order = [c.replace("/", "~") for c in self.record.get("chunks", [])]
        present = {n: a for n, a in node.arrays()}
        return [present[c] for c in order if c in present]

    def read_piece(self, name: str, chunk_id: str) -> np.ndarray:
        """Chunk ``chunk_id``'s piece of segmented array ``name`` as it was written
        (local: no ``offset_by`` shift); PrtError if the artifact has no such piece."""
        try:  # the one piece's metadata, not every piece's (a group lists them all)
            piece = self._node(name)[chunk_id.replace("/", "~")]
        except KeyError:
            raise PrtError(self.path / name, f"no piece for chunk {chunk_id!r}") from None
        return self._read_array(piece)

    def read(self, name: str, region: tuple[slice, ...] | None = None) -> np.ndarray:
        """Read an array (or a region of it) into memory, naming a corrupt chunk file."""
        if self.is_segmented(name):
            whole = self._read_segments(name)
            return whole if region is None else whole[region]
        return self._read_array(self._node(name), region)

    def _read_array(self, arr: Any, region: tuple[slice, ...] | None = None) -> np.ndarray:
        try:
            return np.asarray(arr[...] if region is None else arr[region])
        except Exception as exc:  # codec errors come in many types
            bad = _find_bad_chunk(arr) or arr.path
            raise PrtError(self.path / bad, f"corrupt or truncated chunk "
                           f"({type(exc).__name__}: {exc}); re-bake with `prt run --force "
                           f"{self.record.get('stage', 'STAGE')}`") from None

    def segment_offsets(self, name: str) -> np.ndarray | None:
        """What each piece of segmented array ``name`` is shifted by when read (the
        start of the same chunk's piece of its ``offset_by`` array), None if it has no
        ``offset_by``."""
        spec = load_schema(self.record["kind"]).arrays[name]
        if spec.offset_by is None:
            return None
        return np.cumsum([0] + [p.shape[0] for p in self.pieces(spec.offset_by)])

    def _read_segments(self, name: str) -> np.ndarray:
        parts = [self._read_array(p) for p in self.pieces(name)]
        spec = load_schema(self.record["kind"]).arrays[name]
        starts = self.segment_offsets(name)
        if starts is not None:
            parts = [part + starts[i] for i, part in enumerate(parts)]
        if not parts:
            return np.zeros((0, *([0] * (len(spec.dims) - 1))), spec.dtype)
        return np.concatenate(parts).astype(spec.dtype, copy=False)

    def read_all(self) -> dict[str, np.ndarray]:
        return {name: self.read(name) for name in self.names}


def _find_bad_chunk(arr: Any) -> str | None:
    """The relative path of the first chunk of ``arr`` that fails to decode."""
    grid = [range(-(-s // c)) for s, c in zip(arr.shape, arr.chunks, strict=True)]
    for index in itertools.product(*grid):
        region = tuple(slice(i * c, (i + 1) * c) for i, c in zip(index, arr.chunks, strict=True))
        try:
            arr[region]
        except Exception:
            return "/".join([arr.path, "c", *map(str, index)])
    return None


def open_group(path: Path) -> Artifact:
    """Open any prt group (artifact or cached chunk) for reading."""
    import zarr

    record = read_record(path)
    if record is None:
        raise PrtError(path, "artifact not found; run `prt run` first")
    if record.get("complete") is False:
        raise PrtError(path, "artifact is incomplete (a run was interrupted); `prt run` "
                       "finishes it")
    try:
        group = zarr.open_group(store=str(path), mode="r", zarr_format=3)
    except Exception as exc:
        raise PrtError(path, f"cannot open zarr group ({exc})") from None
    return Artifact(path, group, record)


def open_artifact(path: Path, kind: str | None = None) -> Artifact:
    """Open an artifact and check its kind and schema version against data_schema/."""
    artifact = open_group(path)
    record = artifact.record
    stored_kind = record.get("kind")
    schema = load_schema(kind or stored_kind) if (kind or stored_kind) else None
    if schema is None:
        raise PrtError(path, "record names no artifact kind")
    schema.check_header(stored_kind, record.get("schema_version"), str(path))
    return artifact
