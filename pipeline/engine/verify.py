"""``prt verify``: check every stored artifact of a work directory, reading every chunk.

What is checked, per artifact (``*.zarr`` anywhere under the work directory: the stage
artifacts, ``reference/``, evaluate's ``sweep/<method>/``):

* its provenance record: present, parseable, complete (not left half-written by an
  interrupted run), with the fields its writer records; kind and schema version known;
* every array the schema declares is present, with the declared dtype and rank, and the
  schema's required attributes are present and typed; a segmented array has a piece
  for every chunk of the record;
* every chunk of every array is read and decoded: the zstd frame checksum of each chunk
  file is verified on the way (pipeline/engine/store.py ``compressors``), and the chunk must
  decode to its declared shape and dtype; a floating-point chunk must be finite (the
  runner refuses NaN and Inf when a stage writes, pipeline/engine/runner.py);
* for a stage artifact, every chunk's marker (``.chunks/<stage>/<chunk>.json``) is
  present and carries the key and output digest the artifact's record holds.

What cannot be checked (reported in :attr:`VerifyReport.unchecked`):

* zarr does not store a chunk that is all zeros (the fill value): such a chunk reads as
  zeros, and so would a chunk file deleted from disk; the two cannot be told apart;
* an array written without the frame checksum (by an older prt) is only checked as far
  as zstd decoding goes;
* attributes (``zarr.json``) carry no checksum: they are parsed and checked against the
  schema, but a changed number in them reads as valid;
* the checksum guards against accidents (bit rot, truncated copies), not tampering: a
  chunk re-encoded on purpose with other numbers verifies.

Nothing here writes: verifying is safe on a read-only work directory, and leaves every
file as it was.
"""

from __future__ import annotations

import contextlib
import fcntl
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.engine.chunkwrite import read_marker, segment_name
from pipeline.engine.schema import Schema, load_schema
from pipeline.engine.store import Workdir, read_record
from pipeline.errors import PrtError

# Record fields each writer stores (pipeline/engine/chunkwrite.py for stages, store.write_artifact
# for references): a record without them was not written by a finished prt run.
STAGE_RECORD = ("kind", "schema_version", "stage", "key", "chunks", "chunk_keys",
                "chunk_digests", "digest", "complete")
WHOLE_RECORD = ("kind", "schema_version", "stage", "key")


@dataclass(frozen=True)
class Problem:
    """One bad thing found: in ``artifact``, ``array`` (a zarr path inside it, or None for
    the artifact's record and markers), ``chunk`` (a zarr chunk index such as ``0,1,0``,
    or a stage chunk id for a marker; None for the whole array or artifact)."""

    artifact: Path
    array: str | None
    chunk: str | None
    problem: str
    stage: str | None  # the stage that writes the artifact (None: not a stage artifact)
    resumes: bool = False  # an interrupted write: a plain `prt run` finishes it

    def where(self) -> str:
        """``ARTIFACT[: array A][, chunk C]`` in words."""
        parts = [str(self.artifact)]
        if self.array is not None:
            parts.append(f"array {self.array}")
        if self.chunk is not None:
            parts.append(f"chunk {self.chunk}")
        return ", ".join(parts)


@dataclass
class VerifyReport:
    """What :func:`verify` read and found. Counts: artifacts, arrays (segment pieces
    counted one by one), chunk positions (``chunks``, of which ``stored`` had a file;
    the rest read as zeros) and markers checked."""

    root: Path
    artifacts: int = 0
    arrays: int = 0
    chunks: int = 0
    stored: int = 0
    markers: int = 0
    bytes_read: int = 0
    problems: list[Problem] = field(default_factory=list)
    unchecked: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def bad_artifacts(self) -> list[Path]:
        return sorted({p.artifact for p in self.problems})


def find_artifacts(root: Path) -> list[Path]:
    """Every ``*.zarr`` group under ``root`` (not inside another one, not in ``.tmp``)."""
    found: list[Path] = []

    def walk(folder: Path) -> None:
        for child in sorted(folder.iterdir()):
            if not child.is_dir() or child.name == ".tmp":
                continue
            if child.name.endswith(".zarr"):
                found.append(child)
            else:
                walk(child)

    walk(root)
    return found


@contextlib.contextmanager
def _shared_locks(root: Path) -> Iterator[None]:
    """Hold a shared lock on every work directory's ``.lock`` under ``root`` (without
    creating or changing any file): a run writing there would make chunks read as
    corrupt, so refuse while one does, and keep one from starting meanwhile."""
    with contextlib.ExitStack() as stack:
        for lock in sorted(p for p in root.rglob(".lock") if ".zarr" not in p.as_posix()):
            handle = stack.enter_context(open(lock, "rb"))
            try:
                fcntl.flock(handle, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                raise PrtError(lock.parent, "a prt run is writing this work directory; "
                               "verify it when the run has ended") from None
        yield


def verify(workdir: Workdir, progress: bool = True) -> VerifyReport:
    """Check every artifact under ``workdir`` (see the module docstring). Raises PrtError
    only when there is nothing to verify or a run is writing there; everything found is
    in the report."""
    root = workdir.root
    if not root.is_dir():
        raise PrtError(root, "no such work directory")
    with _shared_locks(root):
        paths = find_artifacts(root)
        if not paths:
            raise PrtError(root, "holds no artifacts (run `prt run` first)")
        report = VerifyReport(root)
        opened = [_open(path, report) for path in paths]
        todo = [o for o in opened if o is not None]
        total = sum(arr.nchunks for o in todo for _, arr in o.arrays)
        from tqdm import tqdm

        with tqdm(total=total, desc="verify", unit="chunk", disable=not progress,
                  leave=False) as bar:
            for o in todo:
                _check_markers(o, report)
                for name, arr in o.arrays:
                    _check_chunks(o, name, arr, report, bar)
        report.artifacts = len(paths)
    report.unchecked = _unchecked(report, [f"{o.path}/{name}" for o in todo
                                           for name in o.without_checksum])
    return report


@dataclass
class _Opened:
    """An artifact whose record and header passed, ready for its chunks to be read."""

    path: Path
    stage: str | None
    record: dict[str, Any]
    schema: Schema
    arrays: list[tuple[str, Any]]  # (zarr path in the group, zarr array)
    without_checksum: list[str]


def _open(path: Path, report: VerifyReport) -> _Opened | None:
    """Check an artifact's record, header and array list; None if its chunks cannot be
    read (the problem is in ``report``)."""
    import zarr

    def bad(problem: str, stage: str | None = None, array: str | None = None,
            resumes: bool = False) -> None:
        report.problems.append(Problem(path, array, None, problem, stage, resumes))

    try:
        record = read_record(path)
    except PrtError as exc:
        bad(exc.problem)
        return None
    if record is None:
        bad("no zarr.json: not an artifact, or its metadata was deleted")
        return None
    is_stage = "chunks" in record or "chunk_keys" in record
    stage = record.get("stage") if isinstance(record.get("stage"), str) and \
        record.get("stage") != "reference" else None
    if record.get("complete") is False:
        bad("incomplete: a run was interrupted while writing it", stage, resumes=True)
        return None
    missing = [k for k in (STAGE_RECORD if is_stage else WHOLE_RECORD) if k not in record]
    if missing:
        bad(f"provenance record lacks {', '.join(missing)}", stage)
        return None
    try:
        schema = load_schema(record["kind"])
        schema.check_header(record["kind"], record["schema_version"], str(path))
        group = zarr.open_group(store=str(path), mode="r", zarr_format=3)
        schema.check_attrs({k: v for k, v in group.attrs.items() if k != "prt"}, str(path))
    except PrtError as exc:
        bad(exc.problem, stage)
        return None
    except Exception as exc:  # zarr raises many types for unreadable metadata
        bad(f"cannot open zarr group ({_one_line(exc)})", stage)
        return None
    arrays: list[tuple[str, Any]] = []
    for name, spec in schema.arrays.items():
        try:
            node = group[name]
        except Exception as exc:  # absent, or unreadable array metadata
            bad(f"array missing or unreadable ({_one_line(exc)})", stage, name)
            continue
        if spec.write == "segments":
            present = {n: a for n, a in node.arrays()}
            for chunk in record.get("chunks", []):
                piece = present.get(segment_name(chunk))
                if piece is None:
                    bad(f"no piece for chunk {chunk}", stage, name)
                else:
                    arrays.append((piece.path, piece))
        else:
            arrays.append((name, node))
    without = []
    for name, arr in list(arrays):
        spec = schema.arrays[name.partition("/")[0]]
        if arr.dtype != spec.dtype or arr.ndim != len(spec.dims):
            bad(f"stored as {arr.dtype} with {arr.ndim} dimensions, schema {schema.kind} "
                f"declares {spec.dtype} with {len(spec.dims)}", stage, name)
            arrays.remove((name, arr))
        elif not _has_checksum(arr):
            without.append(name)
    report.arrays += len(arrays)
    return _Opened(path, stage, record, schema, arrays, without)


def _has_checksum(arr: Any) -> bool:
    """Whether the array's codecs include zstd with its frame checksum on."""
    return any(type(c).__name__ == "ZstdCodec" and getattr(c, "checksum", False)
               for c in arr.metadata.codecs)


def _check_markers(o: _Opened, report: VerifyReport) -> None:
    """Every chunk of a stage artifact has a marker with the record's key and digest."""
    if o.stage is None or "chunks" not in o.record:
        return
    wd = Workdir(o.path.parent)
    keys, digests = o.record["chunk_keys"], o.record["chunk_digests"]
    for chunk in o.record["chunks"]:
        report.markers += 1
        marker = read_marker(wd.marker(o.stage, chunk))
        problem = ("marker missing or unreadable" if marker is None else
                   "marker's key differs from the artifact's record"
                   if marker.get("key") != keys.get(chunk) else
                   "marker's output digest differs from the artifact's record"
                   if marker.get("digest") != digests.get(chunk) else None)
        if problem:
            report.problems.append(Problem(o.path, None, chunk, f"{problem} "
                                           f"({wd.marker(o.stage, chunk)})", o.stage))


def _check_chunks(o: _Opened, name: str, arr: Any, report: VerifyReport, bar: Any) -> None:
    """Read and decode every chunk of one zarr array (each its own read, so that every
    bad chunk is named), checking shape and finiteness."""
    folder = o.path / arr.path
    encoding = arr.metadata.chunk_key_encoding
    floating = arr.dtype.kind in "fc"
    for index in np.ndindex(*arr.cdata_shape):
        report.chunks += 1
        bar.update()
        file = folder / encoding.encode_chunk_key(index)
        if not file.is_file():
            continue  # an all-zero chunk is not stored (see the module docstring)
        report.stored += 1
        report.bytes_read += file.stat().st_size
        region = tuple(slice(i * c, min((i + 1) * c, s))
                       for i, c, s in zip(index, arr.chunks, arr.shape, strict=True))
        label = ",".join(map(str, index)) or "0"
        try:
            data = np.asarray(arr[region])
        except Exception as exc:  # codec errors come in many types
            report.problems.append(Problem(o.path, name, label, "corrupt or truncated "
                                           f"chunk ({_one_line(exc)})", o.stage))
            continue
        expected = tuple(r.stop - r.start for r in region)
        if data.shape != expected or data.dtype != arr.dtype:
            report.problems.append(Problem(o.path, name, label, f"decoded to {data.dtype} "
                                           f"{data.shape}, expected {arr.dtype} {expected}",
                                           o.stage))
        elif floating and not np.isfinite(data).all():
            count = int(data.size - np.isfinite(data).sum())
            report.problems.append(Problem(o.path, name, label,
                                           f"{count} NaN or Inf values", o.stage))


def _unchecked(report: VerifyReport, without_checksum: list[str]) -> list[str]:
    """What the report cannot vouch for, in words."""
    out = []
    if without_checksum:
        more = f" and {len(without_checksum) - 1} more" if len(without_checksum) > 1 else ""
        out.append(f"{without_checksum[0]}{more} were written without chunk checksums (by "
                   "an older prt): a changed byte that still decodes is not detected; "
                   "`prt run --force STAGE` rewrites them with checksums")
    absent = report.chunks - report.stored
    if absent:
        out.append(f"{absent} of {report.chunks} chunk positions have no file: zarr does "
                   "not store all-zero chunks, and they read as zeros; a chunk file "
                   "deleted from disk would read the same")
    out.append("attributes (zarr.json) have no checksum: they are parsed and checked "
               "against the schema only")
    return out


def _one_line(exc: Exception) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def rebake_command(problem: Problem, root: Path) -> str:
    """The command that writes the damaged part again; an artifact of a view baked at
    another image size (``root/views/WxH/``) needs that ``--size``."""
    relative = problem.artifact.relative_to(root).parts if \
        problem.artifact.is_relative_to(root) else ()
    size = f" --size {relative[1]}" if len(relative) > 2 and relative[0] == "views" else ""
    if problem.resumes:
        return f"prt run{size}"
    if problem.stage is not None:
        return f"prt run{size} --force {problem.stage}"
    return f"delete {problem.artifact} (the next command that needs it renders it again)"
