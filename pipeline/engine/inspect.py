"""Inspection API: a scene's work directory and its artifacts as lazy xarray Datasets
with their provenance (issue 18, item 3).

    >>> from pipeline import inspect
    >>> work = inspect.open_workdir(".prt/cornell_box")
    >>> work.artifacts()                  # {"geometry": Path(...), "d2i.transfer": ..., ...}
    >>> ds = work.dataset("geometry")     # or inspect.open_dataset(path)
    >>> ds["vertices"].dims               # ('vertex', 'xyz'): the schema's dimension names
    >>> ds.attrs["prt"]["seconds"]        # the provenance record (key, chunk seconds, ...)
    >>> ds["vertices"][:10].values        # reads only what is asked for

Every array is a dask array over the artifact's zarr chunks, so a multi-GB artifact
opens at once and a slice reads only the chunks under it. A segmented array (one piece
per stage chunk, data_schema/*.yaml ``write: segments``) is the concatenation of its
pieces in chunk order, and an ``offset_by`` array's pieces are shifted by where the
other array's piece starts — exactly what :meth:`pipeline.engine.store.Artifact.read` returns.
An array named like one of its own dimensions (geometry's ``uv``, dims vertex × uv)
is, by xarray's rule, a coordinate rather than a data variable: ``ds["uv"]`` reads it
all the same. ``ds.attrs`` holds the artifact's attributes and, under ``"prt"``, the
provenance record (kind, schema version, stage, key and its parts, seconds, chunk
seconds, software versions). Kind and schema version are checked as the stages check
them.

xarray and dask are imported here only: ``prt status`` and the bakes never load them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pipeline.engine.schema import ArraySpec, load_schema
from pipeline.engine.store import Artifact, open_artifact
from pipeline.errors import PrtError


def open_dataset(path: str | Path) -> Any:
    """The artifact at ``path`` (a ``<stage>.zarr`` folder) as an ``xarray.Dataset``:
    one variable per stored array (dims from its schema), dask-backed, with the
    artifact's attributes and its provenance record under ``attrs["prt"]``."""
    import xarray as xr

    artifact = open_artifact(Path(path))
    schema = load_schema(artifact.record["kind"])
    variables = {name: (spec.dims, _lazy(artifact, spec))
                 for name, spec in schema.arrays.items() if name in artifact.names}
    try:
        return xr.Dataset(variables, attrs={**artifact.attrs, "prt": artifact.record})
    except ValueError as exc:  # e.g. a dimension of two lengths: not a valid artifact
        raise PrtError(Path(path), f"does not open as a dataset: {exc}") from None


def _lazy(artifact: Artifact, spec: ArraySpec) -> Any:
    """One array as a dask array (segmented: its pieces concatenated, offsets added)."""
    import dask.array as da

    if not artifact.is_segmented(spec.name):
        return da.from_zarr(artifact.array(spec.name))
    pieces = [da.from_zarr(piece) for piece in artifact.pieces(spec.name)]
    starts = artifact.segment_offsets(spec.name)
    if starts is not None:
        pieces = [piece + start for piece, start in zip(pieces, starts, strict=False)]
    if not pieces:
        return da.zeros((0, *([0] * (len(spec.dims) - 1))), dtype=spec.dtype)
    return da.concatenate(pieces).astype(spec.dtype)


class WorkdirView:
    """A scene's work directory (``./.prt/<scene>`` by default) for reading: which
    artifacts it holds and each as a dataset. Artifacts of runs at another image size
    (``views/<W>x<H>/``) are named ``"<stage>@<W>x<H>"``."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise PrtError(self.root, "work directory not found; run `prt run` first")

    def artifacts(self) -> dict[str, Path]:
        """Artifact name → folder, for every ``*.zarr`` artifact present."""
        found = {p.name.removesuffix(".zarr"): p for p in sorted(self.root.glob("*.zarr"))}
        for view in sorted(self.root.glob("views/*")):
            found.update({f"{p.name.removesuffix('.zarr')}@{view.name}": p
                          for p in sorted(view.glob("*.zarr"))})
        return found

    def dataset(self, name: str) -> Any:
        """The artifact ``name`` (a key of :meth:`artifacts`) as :func:`open_dataset`."""
        found = self.artifacts()
        if name not in found:
            raise PrtError(self.root, f"no artifact {name!r}; present: "
                           f"{', '.join(found) or 'none'}")
        return open_dataset(found[name])


def open_workdir(root: str | Path) -> WorkdirView:
    """A work directory to inspect (:class:`WorkdirView`)."""
    return WorkdirView(root)
