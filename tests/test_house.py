"""The house rules of docs/architecture.md, checked on the code's own imports (module
level and inside functions, read with ``ast``; nothing is imported):

* every module of ``pipeline`` imports only modules of its own floor or lower ones, and
  no set of modules imports itself in a loop;
* ``pipeline/math`` is pure NumPy (the standard library, NumPy, SciPy and itself);
* no method imports another method, and nothing outside ``pipeline/methods`` names a
  method's module (the core reads methods through the registry);
* ``pipeline/`` holds at most 10 modules at its top level;
* removing a method's folder (its Python, kernels, schemas and stage declarations) leaves
  the other methods whole: in a copy of the project without it every module imports,
  ``prt methods`` lists the others and each of them renders its tiny scene.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import PROJECT, SHARED_DATA

from pipeline.images import read_exr

PACKAGE = PROJECT / "pipeline"
BUILT_IN = ("d2i", "triple", "sg")  # the methods with folders of their own beyond a descriptor

# Floors, lowest first: a module may import its own floor and those below. The first
# prefix that matches a module's name gives its floor.
FLOORS = (
    ("pipeline.errors", "pipeline.math", "pipeline.searchpath", "pipeline.yamlfile"),
    ("pipeline.images",),
    ("pipeline.device", "pipeline.scene"),
    ("pipeline.engine",),
    ("pipeline.method", "pipeline.render", "pipeline.stages"),
    ("pipeline.methods", "pipeline.registry"),
    ("pipeline.job",),
    ("pipeline.evaluation", "pipeline.view"),
    ("pipeline.cli", "pipeline.__main__"),
)
PURE_MATH = {"__future__", "numpy", "scipy", "math", "dataclasses", "functools",
             "collections", "typing", "itertools"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PROJECT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(root: Path = PACKAGE) -> dict[str, Path]:
    return {module_name(p): p for p in sorted(root.rglob("*.py"))}


def imports(path: Path, known: set[str]) -> set[str]:
    """The modules ``path`` imports (absolute names; ``from a import b`` counts as
    ``a.b`` when that is a module, else as ``a``)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.add(sub if sub in known else node.module)
    return found


def floor(module: str) -> int:
    for level, prefixes in enumerate(FLOORS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return level
    if module == "pipeline":
        return 0  # the package's face: its version, nothing else
    raise AssertionError(f"{module}: on no floor of FLOORS (add it there)")


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    known = set(modules())
    return {name: {m for m in imports(path, known) if m in known}
            for name, path in modules().items()}


def test_every_module_imports_only_its_floor_and_below(graph):
    upward = sorted(f"{a} (floor {floor(a)}) imports {b} (floor {floor(b)})"
                    for a, targets in graph.items() for b in targets if floor(b) > floor(a))
    assert upward == []


def test_no_modules_import_each_other_in_a_loop(graph):
    # Tarjan's strongly connected components; a component of more than one module, or a
    # module importing itself, is a loop.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    loops: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph[v]:
                loops.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for v in graph:
        if v not in index:
            visit(v)
    assert loops == []


def test_the_rules_can_fail():
    """The loop and floor checks see a loop and an upward import when there is one."""
    assert floor("pipeline.engine.runner") < floor("pipeline.methods.d2i.render")
    known = {"pipeline.a", "pipeline.b"}
    source = "from pipeline import b\n\ndef f():\n    from pipeline.a import x\n"
    path = PROJECT / "tests" / "__house_probe__.py"
    try:
        path.write_text(source)
        assert imports(path, known) == {"pipeline.b", "pipeline.a"}
    finally:
        path.unlink()


def test_math_is_pure_numpy():
    impure = {name: sorted(m for m in imports(path, set(modules()))
                           if m.split(".")[0] not in PURE_MATH
                           and not m.startswith("pipeline.math"))
              for name, path in modules(PACKAGE / "math").items()}
    assert {k: v for k, v in impure.items() if v} == {}


def test_no_method_imports_another_and_the_core_names_none(graph):
    def method_of(module: str) -> str | None:
        parts = module.split(".")
        return parts[2] if len(parts) > 2 and parts[1] == "methods" else None

    crossing = sorted(f"{a} imports {b}" for a, targets in graph.items() for b in targets
                      if method_of(b) is not None and method_of(a) != method_of(b))
    assert crossing == []


def test_stage_code_versions_hold_no_engine_planning_or_registry():
    """A stage's code version is the import closure of its module, parent packages
    included (decision 0007): no stage's may hold the planner, the runner, the
    registry or the commands, or editing them would re-key every bake."""
    from pipeline import job
    from pipeline.engine.codeversion import module_closure
    from pipeline.engine.planning import impl_target

    outside = {"pipeline.engine.planning", "pipeline.engine.runner", "pipeline.registry",
               "pipeline.job", "pipeline.cli", "pipeline.evaluation.evaluate"}
    held = {name: sorted(outside & set(module_closure([impl_target(spec.impl)])))
            for name, spec in job.stages().stages.items()}
    assert {name: mods for name, mods in held.items() if mods} == {}
    assert len(held) >= 19  # every built-in stage was looked at


def test_the_core_names_no_method_in_its_code():
    """No module outside pipeline/methods holds a method's name as a string (a method is
    found through the registry; the default one by its descriptor's ``default``). The
    name ``direct`` is left out: it is also a transport of the reference renderer."""
    names = {p.name for p in (PACKAGE / "methods").iterdir()
             if p.is_dir() and p.name.isidentifier()} - {"direct"}
    found = sorted(f"{module}:{node.lineno} {node.value!r}"
                   for module, path in modules().items()
                   if not module.startswith("pipeline.methods.")
                   for node in ast.walk(ast.parse(path.read_text()))
                   if isinstance(node, ast.Constant) and node.value in names)
    assert names >= {"d2i", "triple", "sg"}
    assert found == []


def test_the_top_level_holds_at_most_ten_modules():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= 10, top


def _copy_without(method: str, target: Path) -> Path:
    """The project copied to ``target`` without ``method``'s folders."""
    ignore = shutil.ignore_patterns("__pycache__", ".prt", "*.egg-info", ".venv", ".git",
                                    "frames", "benchmarks", "docs", "examples")
    shutil.copytree(PROJECT, target, ignore=ignore)
    for folder in (f"pipeline/methods/{method}", f"kernels/{method}", f"data_schema/{method}"):
        shutil.rmtree(target / folder)
    return target


def _tiny_scene(folder: Path, method: str) -> Path:
    """The scene fuzzer's unmutated scene of ``method`` (tests/scene_fuzz.py)."""
    from scene_fuzz import _base, write_case

    return write_case(_base(method, 12), folder)


@pytest.mark.parametrize("removed", BUILT_IN)
def test_removing_a_method_leaves_the_others_whole(removed, tmp_path):
    """In a copy without ``removed``: every remaining module imports, ``prt methods``
    lists the other methods, and each renders its tiny scene to a finite frame."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    copy = _copy_without(removed, tmp_path / "project")
    env = {**os.environ, "PYTHONPATH": str(copy), "PRT_DATA": str(SHARED_DATA),
           "PRT_JOBS": "1"}
    env.pop("PRT_PLUGINS", None)
    names = sorted(module_name(p) for p in PACKAGE.rglob("*.py")
                   if f"methods/{removed}" not in p.as_posix() and p.name != "__main__.py")
    probe = "import importlib, sys\nfor m in sys.argv[1:]:\n    importlib.import_module(m)\n"
    done = subprocess.run([sys.executable, "-c", probe, *names], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    listed = subprocess.run([sys.executable, "-m", "pipeline", "methods", "--json"],
                            cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=300)
    assert listed.returncode == 0, listed.stderr[-2000:]
    where = subprocess.run([sys.executable, "-c", "import pipeline; print(pipeline.__file__)"],
                           cwd=tmp_path, env=env, capture_output=True, text=True).stdout
    assert Path(where.strip()).is_relative_to(copy)  # the copy ran, not the checkout
    methods = set(json.loads(listed.stdout))
    others = {m for m in BUILT_IN if m != removed}
    assert methods == others | {"direct"}
    for method in sorted(others):
        scene = _tiny_scene(tmp_path / method, method)
        out = tmp_path / method / "frame.exr"
        rendered = subprocess.run(
            [sys.executable, "-m", "pipeline", "render", str(scene), "--method", method,
             "--out", str(out), "--workdir", str(tmp_path / method / "w"), "-q"],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
        assert rendered.returncode == 0, rendered.stderr[-2000:]
        assert np.isfinite(read_exr(out)).all()
    stages = yaml.safe_load((copy / "stages.yaml").read_text())["stages"]
    assert not any(name.startswith(f"{removed}.") for name in stages)
