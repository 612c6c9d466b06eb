"""OpenCL devices: which implementations are here, which of them work, which one is used.

The device is chosen by proof, not by name (decision 0002). In order:

1. ``PRT_CL_DEVICE``, if set: ``cpu`` (the CPU implementations below), ``gpu`` (the GPUs),
   or ``PLATFORM_SUBSTRING[:DEVICE_INDEX]`` (e.g. ``NVIDIA:0``, ``Intel``, ``Oclgrind``);
2. else the first GPU that passes the probe;
3. else the CPU implementations in ``CPU_ORDER`` (Intel's CPU runtime, then PoCL: the
   faster first, benchmarks/engine/opencl_cpus.py), then any other CPU device.

Every candidate is proved before it is used: :data:`PROBE_SOURCE` built and run on it,
its answer checked exactly. A probe's result is cached per machine (``devices.json`` in
the cache folder, :func:`cache_dir`) under a key of the implementation's and driver's
versions, the CPU model, the probe's source and the runtimes' settings in the
environment (``POCL_*``, ``CL_CONFIG_*``), so each process after the first pays nothing.

PoCL comes with pyopencl. On a CPU its LLVM does not know (pyopencl's PoCL 3.0 is LLVM
14: AMD Zen 5 is "generic" to it) nothing builds, so Intel's CPU runtime is installed
too (``intel-opencl-rt`` and ``intel-cmplr-lib-rt``, dependencies on x86-64 Linux; it
runs on AMD CPUs as well). pip puts it in the environment's ``lib/``, where no OpenCL
loader looks: :func:`register_runtimes` gives the loader a vendors folder naming it
(beside the system's own ICD files) before OpenCL first starts in the process, so no one
sets a variable. Oclgrind (a simulator that claims to be every kind of device) is used
only when ``PRT_CL_DEVICE`` names it. Why so, and the measurements:
decision 0002.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path
from typing import Any

from pipeline.errors import PrtError

ENV_DEVICE = "PRT_CL_DEVICE"
# CPU implementations, the faster first. benchmarks/engine/opencl_cpus.py on an AMD EPYC
# (Zen 4, 2 cores), each method's default scene at 64², PoCL's time over Intel's: frames
# d2i 0.93, triple 1.62, sg 1.34; bakes 1.06, 0.95, 0.99 (triple's were 0.20 and 0.64
# before kernels/vectorize.h). PoCL is the fallback where Intel's runtime is missing
# (not x86-64 Linux) or fails.
CPU_ORDER = ("intel-cpu", "pocl")
# Never chosen unless PRT_CL_DEVICE names them.
SIMULATORS = ("oclgrind",)
SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
# How to get a CPU device where none works (x86-64: Intel's runtime runs on any vendor's CPU).
INSTALL_HINT = "pip install intel-opencl-rt intel-cmplr-lib-rt"

# A tiny program that exercises what the kernels rely on: vector loads and stores of
# float3, local memory and barriers across a work-group, integer arithmetic. Every value
# is a small integer, so the answer is exact on any conforming implementation.
PROBE_SOURCE = """
__kernel void prt_probe(__global const float* a, __global float* out, __local float* sum) {
    int i = get_global_id(0), l = get_local_id(0), n = get_local_size(0);
    float3 v = vload3(i, a);
    sum[l] = v.x + v.y + v.z;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int s = n / 2; s > 0; s /= 2) {
        if (l < s) sum[l] += sum[l + s];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    vstore3((float3)(sum[0], v.y * 2.0f, (float)(i % 7)), i, out);
}
"""
PROBE_ITEMS, PROBE_GROUP = 256, 64


def implementation(device: Any) -> str:
    """A short name of the OpenCL implementation behind ``device``: ``pocl``,
    ``intel-cpu``, ``oclgrind``, ``nvidia``, ..., else the platform's name in lower case."""
    name = device.platform.name
    if "Portable Computing Language" in name:
        return "pocl"
    if "Oclgrind" in name:
        return "oclgrind"
    if name.startswith("Intel(R) OpenCL") and _is_cpu(device):
        return "intel-cpu"
    if "NVIDIA" in name:
        return "nvidia"
    return name.lower()


def _is_cpu(device: Any) -> bool:
    import pyopencl as cl

    return bool(device.type & cl.device_type.CPU)


def _is_gpu(device: Any) -> bool:
    import pyopencl as cl

    return bool(device.type & cl.device_type.GPU)


def cache_dir() -> Path:
    """The per-user cache folder: ``$XDG_CACHE_HOME/prt-pipeline`` (default
    ``~/.cache/prt-pipeline``)."""
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "prt-pipeline"


# --- registering runtimes the OpenCL loader does not know of ------------------------------

@dataclass
class Registration:
    """What :func:`register_runtimes` did: the library it registered (None: nothing to
    do), the vendors folder it gave the loader, and why."""

    library: str | None = None
    vendors: str | None = None
    note: str = ""


def intel_cpu_library() -> Path | None:
    """``libintelocl.so`` of an ``intel-opencl-rt`` installed in this Python
    environment, or None."""
    from importlib import metadata

    try:
        files = metadata.files("intel-opencl-rt") or []
    except metadata.PackageNotFoundError:
        return None
    found = [Path(f.locate()).resolve() for f in files if Path(str(f)).name == "libintelocl.so"]
    return next((p for p in found if p.is_file()), None)


def _icd_files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.icd")) if folder.is_dir() else []


def _loader_folders() -> list[Path]:
    """The ICD files' folders the loader reads without us: ``OCL_ICD_VENDORS`` (a folder,
    or one file) if set, else the system's."""
    given = os.environ.get("OCL_ICD_VENDORS")
    return [Path(given)] if given else [SYSTEM_VENDORS]


@cache
def register_runtimes() -> Registration:
    """Make an installed Intel CPU runtime visible to the OpenCL loader of this process
    (and of the processes it starts): a vendors folder in the cache holding an ICD file
    that names it and a copy of every ICD file the loader would have read, given through
    ``OCL_ICD_VENDORS``. Must run before OpenCL first lists platforms in the process
    (:func:`platforms` calls it); does nothing where the runtime is not installed or is
    known to the loader already."""
    library = intel_cpu_library()
    if library is None:
        return Registration(note="Intel's CPU runtime is not installed")
    known: list[Path] = []
    for folder in _loader_folders():
        known += [folder] if folder.is_file() else _icd_files(folder)
    texts = {p.name: p.read_text(errors="replace").strip() for p in known if p.is_file()}
    if any("libintelocl" in text for text in texts.values()):
        return Registration(note="Intel's CPU runtime is registered with the loader already")
    texts["prt-intel-cpu.icd"] = str(library)
    digest = hashlib.sha256(json.dumps(sorted(texts.items())).encode()).hexdigest()[:16]
    try:
        vendors = _write_vendors(cache_dir() / "opencl-vendors" / digest, texts)
    except OSError:  # a read-only home: a private temporary folder
        import tempfile

        vendors = _write_vendors(Path(tempfile.mkdtemp(prefix="prt-opencl-vendors-")), texts)
    os.environ["OCL_ICD_VENDORS"] = str(vendors)
    return Registration(str(library), str(vendors),
                        f"Intel's CPU runtime registered from {library}")


def _write_vendors(folder: Path, texts: dict[str, str]) -> Path:
    """``folder`` holding one ICD file per entry of ``texts`` (written atomically)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in texts.items():
        path = folder / name
        if not path.is_file() or path.read_text(errors="replace").strip() != text:
            tmp = folder / f".{name}.{os.getpid()}"
            tmp.write_text(text + "\n")
            os.replace(tmp, path)
    return folder


# --- proving a device ----------------------------------------------------------------------

@dataclass
class Probe:
    """The probe's result on one device: passed or not, and why not (one line)."""

    ok: bool
    reason: str = ""


def cpu_model() -> str:
    """This machine's CPU: vendor, family, model and name (``/proc/cpuinfo``), else
    ``platform.processor()``."""
    try:
        fields: dict[str, str] = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
        return " ".join(fields.get(k, "?") for k in ("vendor_id", "cpu family", "model",
                                                     "model name"))
    except OSError:
        return platform.processor() or platform.machine()


def versions(device: Any) -> dict[str, str]:
    """The implementation's and the driver's versions as the device reports them (PoCL's
    platform version names its LLVM)."""
    return {"platform": device.platform.version.strip(), "device": device.version.strip(),
            "driver": device.driver_version.strip()}


def probe_key(device: Any) -> str:
    """The probe cache's key for ``device`` on this machine with this environment."""
    settings = sorted((k, v) for k, v in os.environ.items()
                      if k.startswith(("POCL_", "CL_CONFIG_")))
    parts = [device.platform.name, device.name, versions(device), cpu_model(), PROBE_SOURCE,
             settings]
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def run_probe(device: Any) -> Probe:
    """Build (from source, past pyopencl's binary cache) and run :data:`PROBE_SOURCE`
    on ``device``; check every value."""
    import tempfile
    import warnings

    import numpy as np
    import pyopencl as cl

    a = np.arange(3 * PROBE_ITEMS, dtype=np.float32) % 11
    a3 = a.reshape(-1, 3)
    groups = a3.sum(axis=1).reshape(-1, PROBE_GROUP).sum(axis=1)
    index = np.arange(PROBE_ITEMS)
    expected = np.stack([np.repeat(groups, PROBE_GROUP), 2 * a3[:, 1], index % 7], axis=1)
    try:
        context = cl.Context([device])
        queue = cl.CommandQueue(context)
        try:
            with tempfile.TemporaryDirectory() as empty, warnings.catch_warnings():
                warnings.simplefilter("ignore", cl.CompilerWarning)
                program = cl.Program(context, PROBE_SOURCE).build(cache_dir=empty)
        except cl.RuntimeError as exc:
            return Probe(False, "build failed: " + _build_problem(str(exc)))
        if device.max_work_group_size < PROBE_GROUP:
            return Probe(False, f"work-groups of {PROBE_GROUP} items not supported")
        flags = cl.mem_flags
        source = cl.Buffer(context, flags.READ_ONLY | flags.COPY_HOST_PTR, hostbuf=a)
        out = np.zeros((PROBE_ITEMS, 3), np.float32)
        target = cl.Buffer(context, flags.WRITE_ONLY, out.nbytes)
        program.prt_probe(queue, (PROBE_ITEMS,), (PROBE_GROUP,), source, target,
                          cl.LocalMemory(4 * PROBE_GROUP))
        cl.enqueue_copy(queue, out, target)
        queue.finish()
    except cl.Error as exc:  # no context, or the launch failed
        return Probe(False, " ".join(str(exc).split())[:200])
    wrong = int(np.count_nonzero(out != expected))
    if wrong:
        return Probe(False, f"wrong answer: {wrong} of {out.size} values")
    return Probe(True)


def _build_problem(message: str) -> str:
    """What a failed build's message says went wrong, in one line: the status, and the
    log's first ``error`` line (else its first line)."""
    lines = [" ".join(line.split()) for line in message.splitlines()]
    status = lines[0].split(" - ")[0].removeprefix("clBuildProgram failed: ") if lines else ""
    log = [line for line in lines[1:] if line and not line.startswith(
        ("(options:", "Build on", "clBuildProgram failed"))]
    first = next((line for line in log if "error" in line.lower()), log[0] if log else "")
    return f"{status}: {first}"[:240] if first else status[:240]


def probe(device: Any) -> tuple[Probe, bool]:
    """The probe's result for ``device`` and whether it came from the cache (the probe is
    run and its result stored when it is not there)."""
    path, key = cache_dir() / "devices.json", probe_key(device)
    stored = _read_json(path)
    if key in stored:
        return Probe(**stored[key]), True
    result = run_probe(device)
    stored = _read_json(path)  # another process may have written meanwhile
    stored[key] = asdict(result)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(stored, indent=1, sort_keys=True))
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache: probe again next time
    return result, False


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


# --- choosing --------------------------------------------------------------------------------

@dataclass
class Candidate:
    """One OpenCL device as found here: where it comes from, and its probe's result
    (None: not probed, the choice was made before reaching it)."""

    device: Any
    implementation: str
    kind: str  # "gpu", "cpu" or "other"
    probe: Probe | None = None
    cached: bool = False

    def label(self) -> str:
        return f"{self.implementation} ({self.device.name.strip()})"

    def describe(self) -> dict[str, Any]:
        d = self.device
        return {"platform": d.platform.name.strip(), "device": d.name.strip(),
                "implementation": self.implementation, "kind": self.kind,
                "versions": versions(d), "compute_units": int(d.max_compute_units),
                "probe": None if self.probe is None else
                {**asdict(self.probe), "cached": self.cached}}


@dataclass
class Choice:
    """The device the project uses, and why."""

    device: Any
    reason: str


def platforms() -> list[Any]:
    """OpenCL platforms of this process, after :func:`register_runtimes`; [] if none."""
    import pyopencl as cl

    register_runtimes()
    try:
        return cl.get_platforms()
    except cl.Error:  # the loader found no platform at all
        return []


def candidates() -> list[Candidate]:
    """Every device of every platform: GPUs first, then CPUs in ``CPU_ORDER``, then the
    rest (simulators last)."""
    found = []
    for p in platforms():
        try:
            devices = p.get_devices()
        except Exception:  # a platform without devices raises
            devices = []
        for d in devices:
            impl = implementation(d)
            kind = "other" if impl in SIMULATORS else \
                "gpu" if _is_gpu(d) else "cpu" if _is_cpu(d) else "other"
            found.append(Candidate(d, impl, kind))

    def rank(c: Candidate) -> tuple[int, int]:
        order = {"gpu": 0, "cpu": 1, "other": 2}[c.kind]
        within = CPU_ORDER.index(c.implementation) if c.implementation in CPU_ORDER \
            else len(CPU_ORDER)
        return order, within

    return sorted(found, key=rank)  # stable: platform order within a rank


def choose(found: list[Candidate] | None = None) -> Choice:
    """The device to use (module docstring) among ``found`` (default: :func:`candidates`),
    every candidate tried on the way probed. Raises PrtError naming what was tried and
    why each failed when none works."""
    choice = os.environ.get(ENV_DEVICE, "").strip()
    everything = candidates() if found is None else found
    if choice.lower() in ("", "cpu", "gpu"):
        wanted = [c for c in everything if c.kind == choice.lower()] if choice else \
            [c for c in everything if c.kind in ("gpu", "cpu")]
        rule = f"{ENV_DEVICE}={choice}: " if choice else ""
    else:
        name, _, index = choice.partition(":")
        named = [c for c in everything if name.lower() in c.device.platform.name.lower()]
        try:
            wanted = named[int(index or 0):][:1]
        except ValueError:
            raise PrtError(None, f"{ENV_DEVICE}={choice!r}: expected PLATFORM[:INDEX], "
                                 "cpu or gpu") from None
        rule = f"{ENV_DEVICE}={choice}: "
    for c in wanted:
        c.probe, c.cached = probe(c.device)
        if c.probe.ok:
            why = "the first GPU that passed the probe" if c.kind == "gpu" else \
                f"the first CPU implementation that passed the probe (order: " \
                f"{', '.join(CPU_ORDER)}, then any other)" if c.kind == "cpu" else \
                "named"
            return Choice(c.device, rule + why)
    raise PrtError(None, no_device_message(choice, wanted, everything))


def no_device_message(choice: str, tried: list[Candidate], everything: list[Candidate]) -> str:
    """One line: what was looked for, each candidate tried and why it failed, the fix."""
    if choice and not tried:
        have = ", ".join(c.label() for c in everything) or "none"
        return f"{ENV_DEVICE}={choice!r}: no such OpenCL device (have: {have})"
    failures = "; ".join(f"{c.label()}: {c.probe.reason}" for c in tried if c.probe) \
        or "no OpenCL device found"
    fix = f"`{INSTALL_HINT}` (Intel's CPU runtime, any x86-64 CPU)" \
        if intel_cpu_library() is None else \
        "an OpenCL driver that builds for this machine (a GPU's, or PoCL 5 or newer)"
    what = f" for {ENV_DEVICE}={choice}" if choice else ""
    return f"no working OpenCL device{what}: {failures}; fix: {fix}"


def report() -> dict[str, Any]:
    """What ``prt devices`` shows: the registration, every device with its versions and
    probe result (all probed), and the choice with its reason (or the error)."""
    registration = register_runtimes()
    everything = candidates()
    try:
        choice = choose(everything)
        chosen: dict[str, Any] = {"device": choice.device.name.strip(),
                                  "platform": choice.device.platform.name.strip(),
                                  "implementation": implementation(choice.device),
                                  "reason": choice.reason}
    except PrtError as exc:
        chosen = {"error": exc.one_line()}
    for c in everything:
        if c.probe is None:
            c.probe, c.cached = probe(c.device)
    return {"chosen": chosen, "devices": [c.describe() for c in everything],
            "registration": asdict(registration), "cpu": cpu_model(),
            "python": sys.version.split()[0], "cpu_order": list(CPU_ORDER),
            "cache": str(cache_dir() / "devices.json")}
