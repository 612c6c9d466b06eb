"""The project installed as a plain package, away from any checkout, finds its own data.

``pip install --no-deps --target DIR`` of the repository puts the package, its data
(stages.yaml as pipeline/project/stages.yaml, kernels/, data_schema/, the embedded
scenes) and the ``prt`` script under DIR; nothing lands in ``sys.prefix`` (so no
``share/`` folder can be relied on). The commands then run with ``PYTHONPATH=DIR`` from
a folder outside the checkout, so that a checkout cannot be found by accident.

The build needs setuptools >= 68 and wheel: from the package index (build isolation, a
local mirror here) or, failing that, from the running environment. If neither can build
offline the test is skipped, saying why.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import PROJECT

# Signs in pip's output that the build backend could not be had (not a packaging bug).
NO_BUILD_BACKEND = ("No matching distribution found", "Could not find a version",
                    "invalid command 'bdist_wheel'", "Failed to establish a new connection",
                    "Network is unreachable", "Temporary failure in name resolution",
                    "No module named 'setuptools'", "No module named 'wheel'")
# What the repository's copy leaves out: version control, environments, build outputs.
NOT_SOURCE = shutil.ignore_patterns(".git", ".venv", "venv", "build", "dist", "*.egg-info",
                                    "__pycache__", ".pytest_cache", ".ruff_cache", ".prt",
                                    "frames")


def _run(command: list, cwd: Path, env: dict | None = None,
         timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in command], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """DIR after ``pip install --no-deps --target DIR`` of a copy of the repository (the
    copy keeps pip's in-tree build outputs out of the checkout)."""
    root = tmp_path_factory.mktemp("packaging")
    source = root / "source"
    shutil.copytree(PROJECT, source, ignore=NOT_SOURCE)
    outputs = []
    for extra in ([], ["--no-build-isolation"]):
        target = root / ("target-isolated" if not extra else "target-local")
        done = _run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-input",
                     "--disable-pip-version-check", "--quiet", "--target", target, *extra,
                     "."], cwd=source, timeout=300)
        if done.returncode == 0:
            return target
        outputs.append(done.stdout + done.stderr)
    text = "\n".join(outputs)
    if any(sign in text for sign in NO_BUILD_BACKEND):
        line = next(x for x in text.splitlines() if any(s in x for s in NO_BUILD_BACKEND))
        pytest.skip(f"pip cannot build the project offline here: {line.strip()}")
    pytest.fail(f"pip install --target failed:\n{text[-3000:]}")


def _environment(target: Path) -> dict:
    """The caller's environment with only DIR on the module path (no tests/, no toy
    schemas from the checkout)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PRT_SCHEMA_PATH",
                                                            "PRT_KERNEL_PATH")}
    env["PYTHONPATH"] = str(target)
    return env


def test_installed_package_finds_its_stage_file_inside_itself(installed, tmp_path):
    """The package and the stage file it loads both come from DIR (none from the
    checkout), and the stage file parses."""
    probe = ("import pipeline, pipeline.job as j; f = j.stages(); "
             "print(pipeline.__file__); print(f.path); print(' '.join(f.stages))")
    done = _run([sys.executable, "-c", probe], cwd=tmp_path, env=_environment(installed))
    assert done.returncode == 0, done.stderr
    package, stagefile, names = done.stdout.split("\n", 2)
    assert Path(package).resolve().is_relative_to(installed.resolve())
    assert Path(stagefile).resolve() == (installed / "pipeline" / "project"
                                         / "stages.yaml").resolve()
    # every built-in method's own stage file came with it
    assert {"gbuffer", "d2i.transfer", "triple.visibility", "sg.fit"} <= set(names.split())
    assert not (installed / "share").exists()  # nothing relies on a data-files prefix


def test_installed_prt_bakes_the_default_scene(installed, tmp_path):
    """``DIR/bin/prt run --until gbuffer`` bakes the embedded default scene's geometry
    and G-buffer from the installed package alone (schemas, stage file, method
    plug-ins found there; a few seconds) and writes their artifacts."""
    work = tmp_path / "work"
    env = _environment(installed)
    done = _run([installed / "bin" / "prt", "run", "--until", "gbuffer", "--workdir", work,
                 "--quiet"], cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    for stage in ("geometry", "gbuffer"):
        assert (work / f"{stage}.zarr" / "zarr.json").is_file(), sorted(work.glob("*"))
    methods = _run([installed / "bin" / "prt", "methods"], cwd=tmp_path, env=env)
    assert methods.returncode == 0 and "d2i:" in methods.stdout, methods.stderr


def test_installed_package_holds_the_viewer_page(installed, tmp_path):
    """``prt view``'s page and script are package data (pipeline/view/static), read from
    DIR."""
    probe = ("import pipeline.view.server as s; print(s.__file__); "
             "print(len(s.static_text('index.html')), len(s.static_text('app.js')))")
    done = _run([sys.executable, "-c", probe], cwd=tmp_path, env=_environment(installed))
    assert done.returncode == 0, done.stderr
    where, sizes = done.stdout.split("\n", 1)
    assert Path(where).resolve().is_relative_to(installed.resolve())
    assert all(int(n) > 1000 for n in sizes.split())
