"""Exact code versions: the hash of the project code a computation can execute.

A stage's, a renderer's or the reference renderer's code version is the SHA-256 over

* the source of every *project module* in the import closure of its root module(s),
  found statically (``ast``: module-level and function-local ``import`` statements,
  relative imports resolved), where a project module is one of the ``pipeline`` package
  or of the root module's own top-level package (a plug-in under ``tests/`` or
  elsewhere). Third-party libraries are covered by the software versions recorded in
  each artifact, not here;
* every OpenCL kernel those modules use, with its ``#include "..."`` files followed
  transitively. A module uses a kernel when its source names the file as a string
  literal (``cl.kernel("transfer.cl", ...)``: kernels are always loaded by file name),
  or when a stage declares it in stages.yaml.

One function, :func:`code_version`, serves stages, frames and references, so the three
cannot drift apart. Sources are re-read only when a file's size or modification time
changes (``prt status`` parses each module once per process).
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import re
from collections.abc import Iterable
from pathlib import Path

from pipeline.errors import PrtError
from pipeline.searchpath import find_kernel

PROJECT_PACKAGE = "pipeline"
_INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"', re.MULTILINE)
_KERNEL_NAME = re.compile(r"^[\w./-]+\.cl$")


def module_file(module: str) -> Path | None:
    """The source file of ``module`` (without importing it), or None if not found."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    return Path(spec.origin)


_PARSED: dict[tuple[str, int, int], tuple[bytes, tuple[str, ...], tuple[str, ...]]] = {}


def _parse(module: str, path: Path) -> tuple[bytes, tuple[str, ...], tuple[str, ...]]:
    """(source bytes, imported module names, kernel file names) of a module's source."""
    st = path.stat()
    cache_key = (str(path), st.st_size, st.st_mtime_ns)
    if cache_key not in _PARSED:
        source = path.read_bytes()
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        imports: list[str] = []
        kernels: list[str] = []
        for node in ast.walk(ast.parse(source, str(path))):
            if isinstance(node, ast.Import):
                imports.extend(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(node.module, node.level, package)
                imports.append(base)
                # ``from pkg import name``: name may be a submodule
                imports.extend(f"{base}.{alias.name}" for alias in node.names)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and _KERNEL_NAME.match(node.value):
                kernels.append(node.value)
        _PARSED[cache_key] = (source, tuple(imports), tuple(kernels))
    return _PARSED[cache_key]


def _absolute(name: str | None, level: int, package: str) -> str:
    if level == 0:
        return name or ""
    parts = package.split(".")
    base = ".".join(parts[: len(parts) - level + 1])
    return f"{base}.{name}" if name else base


def _parents(module: str) -> list[str]:
    """``a.b.c`` -> [``a``, ``a.b``]: the packages Python imports before the module."""
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def module_closure(roots: Iterable[str]) -> dict[str, Path]:
    """Project modules reachable by imports from ``roots`` (the roots included, and the
    packages they live in), mapped to their source files, sorted by name."""
    roots = list(roots)
    packages = {PROJECT_PACKAGE} | {r.partition(".")[0] for r in roots}
    found: dict[str, Path] = {}
    stack = list(roots)
    for root in roots:
        if module_file(root) is None:
            raise PrtError(None, f"module {root!r} not found")
    while stack:
        module = stack.pop()
        if module in found or module.partition(".")[0] not in packages:
            continue
        path = module_file(module)
        if path is None:
            continue  # an attribute imported from a package, not a module
        found[module] = path
        _, imports, _ = _parse(module, path)
        stack.extend(imports)
        stack.extend(_parents(module))
    return dict(sorted(found.items()))


def kernel_closure(names: Iterable[str]) -> dict[str, Path]:
    """Kernel files ``names`` and every file they ``#include`` (transitively), mapped to
    their paths, sorted by name. Raise PrtError naming a kernel or header not found."""
    found: dict[str, Path] = {}
    stack = list(names)
    while stack:
        name = stack.pop()
        if name in found:
            continue
        path = find_kernel(name)
        if path is None:
            raise PrtError(name, "kernel source not found in the kernel folders")
        found[name] = path
        stack.extend(_INCLUDE.findall(path.read_text()))
    return dict(sorted(found.items()))


def code_version(modules: Iterable[str], kernels: Iterable[str] = ()) -> str:
    """SHA-256 over the sources of the import closure of ``modules`` and of the kernels
    they name (plus ``kernels``), with includes followed. Equal code, equal version."""
    closure = module_closure(modules)
    used = set(kernels)
    for module, path in closure.items():
        used.update(k for k in _parse(module, path)[2] if find_kernel(k) is not None)
    h = hashlib.sha256()
    for module, path in closure.items():
        h.update(f"module {module}\n".encode())
        h.update(_parse(module, path)[0])
    for name, path in kernel_closure(used).items():
        h.update(f"kernel {name}\n".encode())
        h.update(path.read_bytes())
    return h.hexdigest()
