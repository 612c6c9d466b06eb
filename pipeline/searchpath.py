"""Where kernels and artifact schemas are found: the project's folders first (``kernels/``,
then each built-in method's ``kernels/<method>/``; the same for ``data_schema/``), then the
folders that method plug-ins add (:func:`add_kernel_dir`, :func:`add_schema_dir`), then
those listed in ``PRT_KERNEL_PATH`` / ``PRT_SCHEMA_PATH`` (``os.pathsep``-separated).

The project's folders are found in a checkout (``kernels/``, ``data_schema/`` beside the
package) or, in an installed wheel, as the package data ``pipeline.kernels`` and
``pipeline.data_schema``.
"""

from __future__ import annotations

import os
from functools import cache
from importlib.resources import files
from pathlib import Path

_EXTRA: dict[str, list[Path]] = {"kernels": [], "data_schema": []}
_ENV = {"kernels": "PRT_KERNEL_PATH", "data_schema": "PRT_SCHEMA_PATH"}


@cache
def _project_dir(name: str) -> Path:
    """The project's own ``name`` folder (fixed for the process: looked up once — a
    frame looks kernels up dozens of times)."""
    checkout = Path(__file__).resolve().parent.parent / name
    # through the regular package: files() of a folder without __init__.py is a
    # MultiplexedPath, whose str() is no file name
    return checkout if checkout.is_dir() else Path(str(files("pipeline").joinpath(name)))


@cache
def _project_dirs(name: str) -> tuple[Path, ...]:
    """The project's ``name`` folder and its subfolders (one per built-in method that
    has kernels or schemas of its own), sorted."""
    top = _project_dir(name)
    return (top, *sorted(d for d in top.iterdir() if d.is_dir() and d.name.isidentifier()))


def _dirs(kind: str) -> list[Path]:
    env = [Path(p) for p in os.environ.get(_ENV[kind], "").split(os.pathsep) if p]
    return [*_project_dirs(kind), *_EXTRA[kind], *env]


def kernel_dirs() -> list[Path]:
    """Folders searched for OpenCL sources and headers, in order."""
    return _dirs("kernels")


def schema_dirs() -> list[Path]:
    """Folders searched for artifact schema files, in order."""
    return _dirs("data_schema")


def add_kernel_dir(path: Path) -> None:
    """Let kernels (and headers) in ``path`` be found by name (a plug-in's own)."""
    if path not in _EXTRA["kernels"]:
        _EXTRA["kernels"].append(path)


def add_schema_dir(path: Path) -> None:
    """Let schema files in ``path`` be found by kind (a plug-in's own)."""
    if path not in _EXTRA["data_schema"]:
        _EXTRA["data_schema"].append(path)


def find_kernel(name: str) -> Path | None:
    """The first ``<kernel dir>/<name>`` that exists, or None."""
    return next((d / name for d in kernel_dirs() if (d / name).is_file()), None)
