"""pipeline/device/devices.py: the OpenCL device chosen by proof, the fallback when an
implementation cannot build, ``prt devices``, the Intel runtime's registration.

A CPU that PoCL's LLVM does not know (AMD Zen 5) is simulated without touching the
project's code: ``POCL_EXTRA_BUILD_FLAGS="-target-cpu generic"`` makes every PoCL build
fail, as "unknown target CPU 'generic'" does there; ``CL_CONFIG_CPU_TARGET_ARCH=bogus``
does the same to Intel's runtime (no context). Each case runs ``prt`` in a fresh process
with its own probe cache (``XDG_CACHE_HOME``) and no ``PRT_CL_DEVICE``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.device import devices

POCL_BROKEN = {"POCL_EXTRA_BUILD_FLAGS": "-target-cpu generic"}
INTEL_BROKEN = {"CL_CONFIG_CPU_TARGET_ARCH": "bogus"}


def prt(*args, cache: Path, env: dict | None = None, cwd: Path | None = None
        ) -> subprocess.CompletedProcess:
    """``prt ARGS`` with the probe cache in ``cache`` and only ``env``'s device settings."""
    base = {k: v for k, v in os.environ.items()
            if k not in ("PRT_CL_DEVICE", "OCL_ICD_VENDORS") and not k.startswith(
                ("POCL_EXTRA", "CL_CONFIG_CPU_TARGET"))}
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=600,
                          env={**base, "XDG_CACHE_HOME": str(cache), **(env or {})})


def report(cache: Path, env: dict | None = None) -> tuple[dict, subprocess.CompletedProcess]:
    result = prt("devices", "--json", cache=cache, env=env)
    return json.loads(result.stdout), result


def found(info: dict) -> dict[str, dict]:
    return {d["implementation"]: d for d in info["devices"]}


@pytest.fixture(scope="module")
def here(tmp_path_factory) -> dict[str, dict]:
    """The implementations found on this machine, and their probes (a clean run)."""
    info, result = report(tmp_path_factory.mktemp("cache"))
    assert result.returncode in (0, 2), result.stderr
    return found(info)


def need(here: dict, *implementations: str) -> None:
    missing = [i for i in implementations if not here.get(i, {}).get("probe", {}).get("ok")]
    if missing:
        pytest.skip(f"needs a working {', '.join(missing)} here")


def test_the_default_choice_is_a_device_that_passed_its_probe(tmp_path):
    info, result = report(tmp_path)
    assert result.returncode == 0, result.stderr
    chosen = info["chosen"]
    device = next(d for d in info["devices"] if d["implementation"] == chosen["implementation"])
    assert device["probe"]["ok"] and device["kind"] in ("gpu", "cpu")
    assert all(d["implementation"] not in devices.SIMULATORS or d["kind"] == "other"
               for d in info["devices"])
    # the second process reads the probes from the cache
    again, _ = report(tmp_path)
    assert all(d["probe"]["cached"] for d in again["devices"])
    assert again["chosen"] == chosen


def test_pocl_that_cannot_build_is_skipped_and_the_default_scene_runs(here, tmp_path):
    """PoCL cannot build (as on AMD Zen 5): `prt devices` says why it was skipped, and
    `prt run` renders the default scene through Intel's runtime, no variable set."""
    need(here, "intel-cpu")
    info, result = report(tmp_path / "cache", POCL_BROKEN)
    assert result.returncode == 0, result.stderr
    pocl = found(info)["pocl"]["probe"]
    assert not pocl["ok"] and "-target-cpu" in pocl["reason"]
    assert info["chosen"]["implementation"] == "intel-cpu"
    text = prt("devices", cache=tmp_path / "cache", env=POCL_BROKEN).stdout
    assert "probe: FAILED: build failed" in text and "using: intel-cpu" in text
    run = prt("run", "--size", "24x24", "--workdir", tmp_path / "w", "--frames",
              tmp_path / "frames", "-q", cache=tmp_path / "cache", env=POCL_BROKEN,
              cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "frames" / "cornell_box_d2i_24x24.exr").is_file()


def test_intel_that_cannot_start_falls_back_to_pocl(here, tmp_path):
    need(here, "intel-cpu", "pocl")
    info, result = report(tmp_path, INTEL_BROKEN)
    assert result.returncode == 0, result.stderr
    assert "DEVICE_NOT_AVAILABLE" in found(info)["intel-cpu"]["probe"]["reason"]
    assert info["chosen"]["implementation"] == "pocl"


def test_where_both_work_the_faster_is_used(here, tmp_path):
    """The order of devices.CPU_ORDER (Intel's runtime first:
    benchmarks/engine/opencl_cpus.py)."""
    need(here, "intel-cpu", "pocl")
    if any(d["kind"] == "gpu" for d in here.values()):
        pytest.skip("a GPU works here")
    info, _ = report(tmp_path)
    assert info["chosen"]["implementation"] == devices.CPU_ORDER[0] == "intel-cpu"


def test_no_working_device_is_one_error_line_naming_each_failure(here, tmp_path):
    need(here, "intel-cpu", "pocl")
    if any(d["kind"] == "gpu" for d in here.values()):
        pytest.skip("a GPU works here")
    result = prt("render", "--size", "8x8", "--out", tmp_path / "x.exr", cache=tmp_path,
                 env={**POCL_BROKEN, **INTEL_BROKEN}, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: no working OpenCL device: ")
    assert "pocl (" in lines[0] and "intel-cpu (" in lines[0] and "fix: " in lines[0]
    devices_result = prt("devices", cache=tmp_path, env={**POCL_BROKEN, **INTEL_BROKEN})
    assert devices_result.returncode == 2 and "FAILED" in devices_result.stdout


def test_a_named_device_that_is_not_there_is_one_error_line(tmp_path):
    result = prt("devices", cache=tmp_path, env={"PRT_CL_DEVICE": "NoSuchPlatform"})
    assert result.returncode == 2
    assert result.stderr.startswith("error: PRT_CL_DEVICE='NoSuchPlatform': no such OpenCL "
                                    "device (have: ")


def test_a_named_device_whose_probe_fails_is_refused(here, tmp_path):
    need(here, "pocl")
    result = prt("devices", cache=tmp_path, env={"PRT_CL_DEVICE": "Portable", **POCL_BROKEN})
    assert result.returncode == 2
    assert "no working OpenCL device for PRT_CL_DEVICE=Portable: pocl (" in result.stderr


def test_the_probe_cache_key_follows_the_runtime_settings(here, monkeypatch):
    need(here, "pocl")
    from pipeline.device import cl

    device = cl.device()
    key = devices.probe_key(device)
    monkeypatch.setenv("POCL_EXTRA_BUILD_FLAGS", "-O1")
    assert devices.probe_key(device) != key
    monkeypatch.delenv("POCL_EXTRA_BUILD_FLAGS")
    assert devices.probe_key(device) == key


def test_registration_names_the_runtime_beside_the_loaders_own_files(tmp_path, monkeypatch):
    """The vendors folder holds an ICD file naming the installed library and a copy of
    each ICD file the loader would have read; OCL_ICD_VENDORS points at it. Where the
    loader knows the runtime already, nothing is written."""
    system = tmp_path / "etc"
    system.mkdir()
    (system / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    library = tmp_path / "lib" / "libintelocl.so"
    monkeypatch.setattr(devices, "SYSTEM_VENDORS", system)
    monkeypatch.setattr(devices, "intel_cpu_library", lambda: library)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("OCL_ICD_VENDORS", raising=False)
    devices.register_runtimes.cache_clear()
    try:
        done = devices.register_runtimes()
        folder = Path(os.environ["OCL_ICD_VENDORS"])
        assert done.library == str(library) and done.vendors == str(folder)
        assert folder.parent.parent == tmp_path / "cache" / "prt-pipeline"
        assert {p.name: p.read_text().strip() for p in folder.iterdir()} == {
            "nvidia.icd": "libnvidia-opencl.so.1", "prt-intel-cpu.icd": str(library)}
        (system / "intel.icd").write_text("/opt/intel/libintelocl.so\n")
        monkeypatch.delenv("OCL_ICD_VENDORS")
        devices.register_runtimes.cache_clear()
        assert devices.register_runtimes().library is None
        assert "OCL_ICD_VENDORS" not in os.environ
    finally:
        devices.register_runtimes.cache_clear()


@pytest.mark.parametrize("message, expected", [
    ("clBuildProgram failed: BUILD_PROGRAM_FAILURE - clBuildProgram failed: "
     "BUILD_PROGRAM_FAILURE\n\nBuild on <pyopencl.Device 'pthread-AMD EPYC'>:\n\n"
     "error: unknown target CPU 'generic'\nnote: valid target CPU values are: ...\n\n"
     "(options: -I /x)",
     "BUILD_PROGRAM_FAILURE: error: unknown target CPU 'generic'"),
    ("clBuildProgram failed: INVALID_BUILD_OPTIONS - clBuildProgram failed: "
     "INVALID_BUILD_OPTIONS\n\nBuild on <dev>:\n\nInvalid build option: -target-cpu\n\n"
     "(options: -I /x)", "INVALID_BUILD_OPTIONS: Invalid build option: -target-cpu"),
])
def test_a_build_failure_is_told_in_one_line(message, expected):
    assert devices._build_problem(message) == expected
