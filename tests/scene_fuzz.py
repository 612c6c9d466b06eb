"""A scene fuzzer: Hypothesis strategies for scene files and command lines a user might
write — valid and invalid, over every key of ``prt-scene/1`` — and the invariant every
one of them must keep (issue 40):

    exit 0 with a finite frame, or exit 2 with one ``error:`` line and no traceback;
    and afterwards the work directory still answers ``prt status``.

A case starts from a method's tiny scene (tests/tiny_scenes.py: seconds to bake) and
applies a few mutations, each drawn from one family: the camera; a material (every model,
its parameters in and out of range, blends and bumps); an object (primitives of odd
size, transforms that mirror, flatten or fling it far away, OBJ meshes that are
degenerate, inward-wound, open, tiny, huge, malformed); the lights (every kind, odd
values); the environment map (odd sizes, zeros, a sun, NaN, overflow); the settings (any
stage parameter, in and out of its limits); the methods; and the command line
(``--size``, ``--exposure``, ``--option``, ``--set``, ``--env-rotate``).

Used by tests/test_scene_fuzzer.py (a fixed-seed budget in CI) and
benchmarks/engine/fuzz.py (the long run, whose findings become regression tests).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from helpers import small_scene_dict
from hypothesis import strategies as st
from tiny_scenes import SETTINGS

METHODS = ("d2i", "triple", "sg", "direct")
MODELS = ("lambert", "blinn_phong", "ward", "ward_duer", "ward_anisotropic", "lafortune",
          "cook_torrance", "ashikhmin_shirley")
CASE_TIMEOUT = 240  # seconds a case may take (tiny scenes bake in seconds)

# ------------------------------------------------------------------------ values


def numbers(low: float, high: float) -> st.SearchStrategy[float]:
    """Mostly in [low, high]; sometimes just outside, zero, negative, huge or not finite."""
    inside = st.floats(low, high, allow_nan=False, allow_infinity=False)
    odd = st.sampled_from([0.0, -1.0, 1e-12, 1e12, 1e30, float("nan"), float("inf"),
                           low - 1.0, high * 10.0 + 1.0])
    return st.one_of(inside, inside, inside, inside, inside, odd)


def junk() -> st.SearchStrategy[Any]:
    """A value of the wrong kind."""
    return st.sampled_from(["many", "", None, True, [], {}, [1, 2], {"a": 1}, "1e3"])


def vectors(low: float, high: float, length: int = 3) -> st.SearchStrategy[Any]:
    good = st.lists(st.floats(low, high, allow_nan=False), min_size=length, max_size=length)
    bad = st.one_of(st.lists(numbers(low, high), min_size=0, max_size=length + 1), junk())
    return st.one_of(good, good, good, good, good, bad)


def colours() -> st.SearchStrategy[Any]:
    return vectors(0.0, 4.0)


# ------------------------------------------------------------------------ files


def write_map(path: Path, kind: str, height: int) -> Path:
    """An environment map of ``kind`` (odd sizes and values) at ``path``."""
    from pipeline.images import write_exr

    width = 2 * height if kind != "not_twice" else height + 1
    rgb = np.full((height, width, 3), 0.3, np.float32)
    rgb[height // 2:] = 0.05
    if kind == "zeros":
        rgb[:] = 0.0
    elif kind == "sun":
        rgb[height // 4, width // 3] = 1e6
    elif kind == "nan":
        rgb[0, 0, 1] = np.nan
    elif kind == "negative":
        rgb[-1, -1, 0] = -0.5
    elif kind == "overflow":
        rgb[:] = 1e30
    elif kind == "tiny":
        rgb[:] = 1e-30
    write_exr(path, rgb)
    return path


def obj_text(kind: str, scale: float, offset: float) -> str:
    """An OBJ mesh of ``kind``: a closed tetrahedron wound outward or inward, an open
    triangle, degenerate faces, a face naming a missing vertex, a line cut short, NaN."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale + offset
    faces = [(1, 3, 2), (1, 2, 4), (1, 4, 3), (2, 3, 4)]  # outward
    if kind == "inward":
        faces = [(a, c, b) for a, b, c in faces]
    elif kind == "open":
        faces = faces[:1]
    elif kind == "degenerate":
        faces = [*faces, (1, 1, 2), (2, 2, 2)]
        v = np.vstack([v, v[0]])
    elif kind == "missing_vertex":
        faces = [*faces, (1, 2, 9)]
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in v]
    if kind == "nan":
        lines[0] = "v nan 0 0"
    if kind == "cut_short":
        lines[1] = "v 1.0 0"
    lines += [f"f {a} {b} {c}" for a, b, c in faces]
    return "" if kind == "empty" else "\n".join(lines) + "\n"


# ------------------------------------------------------------------------ cases


@dataclass
class Case:
    """A scene document, its extra files (name -> bytes or a map spec), the method and
    the command line's extra arguments."""

    method: str
    doc: dict[str, Any]
    files: dict[str, Any] = field(default_factory=dict)
    args: list[str] = field(default_factory=list)
    mutations: list[str] = field(default_factory=list)

    def describe(self) -> dict[str, Any]:
        return {"method": self.method, "mutations": self.mutations, "args": self.args,
                "scene": self.doc, "files": {k: (v if isinstance(v, (str, list)) else "<bytes>")
                                             for k, v in self.files.items()}}


def _base(method: str, size: int) -> Case:
    doc = small_scene_dict(size)
    doc["name"] = f"fuzz_{method}"
    doc["methods"] = [method]
    doc["settings"] = dict(SETTINGS.get(method, {}))
    files: dict[str, Any] = {}
    if method in ("triple", "sg"):
        files["sky.exr"] = ["map", "plain", 8]
        doc["lights"] = [{"type": "environment", "file": "sky.exr"}]
    return Case(method, doc, files)


@st.composite
def camera_mutation(draw, case: Case) -> str:
    key = draw(st.sampled_from(["position", "look_at", "up", "fov", "width", "height",
                                "inside", "unknown"]))
    cam = case.doc["camera"]
    if key in ("position", "look_at", "up"):
        cam[key] = draw(vectors(-5.0, 5.0))
    elif key == "fov":
        cam[key] = draw(st.one_of(numbers(1.0, 179.0), st.sampled_from([180, 0, 1e-3])))
    elif key in ("width", "height"):
        cam[key] = draw(st.one_of(st.integers(1, 12), st.sampled_from([0, -3, 2.5, 20000])))
    elif key == "inside":  # in the ball (a closed sphere) or the box
        cam["position"], cam["look_at"] = draw(st.sampled_from(
            [([0.6, 0.35, 0.2], [0.6, 0.35, 1.0]), ([-0.6, 0.3, 0.0], [0.0, 0.3, 0.0])]))
    else:
        cam["zoom"] = 2
    return f"camera.{key}"


@st.composite
def material_mutation(draw, case: Case) -> str:
    name = draw(st.sampled_from(sorted(case.doc["materials"])))
    model = draw(st.sampled_from(MODELS))
    m: dict[str, Any] = {"model": model, "albedo": draw(vectors(0.0, 0.9))}
    if model != "lambert":
        low = 0.05 if model in ("ward", "ward_duer", "ward_anisotropic", "cook_torrance") \
            else 1.0
        high = 0.6 if low < 1 else 300.0
        gamma = draw(numbers(low, high))
        m.update(gamma=gamma, specular=draw(numbers(0.0, 0.3)))
        if draw(st.booleans()):
            m["gamma_range"] = draw(st.one_of(
                st.just([low, high]), vectors(0.0, 400.0, 2)))
        extra = {"ward_anisotropic": {"alpha_ratio": numbers(0.1, 10.0)},
                 "lafortune": {"cxy": numbers(-1.0, 1.0), "cz": numbers(-1.0, 1.0)},
                 "cook_torrance": {"f0": numbers(0.0, 1.0), "ior": numbers(1.0, 3.0)},
                 "ashikhmin_shirley": {"f0": numbers(0.0, 1.0)}}.get(model, {})
        for k, strategy in extra.items():
            if draw(st.booleans()):
                m[k] = draw(strategy)
        if draw(st.integers(0, 9)) == 0:
            m["pca_tolerance"] = draw(numbers(0.001, 0.5))
    detail = draw(st.sampled_from(["none", "none", "none", "blend", "bump", "missing"]))
    if detail == "blend":
        other = draw(st.sampled_from(sorted(case.doc["materials"])))
        m["blend"] = {"texture": "mask.png", "material": other}
        case.files["mask.png"] = ["texture"]
    elif detail == "bump":
        m["bump"] = {"texture": "mask.png", "height": draw(numbers(0.0, 0.05))}
        case.files["mask.png"] = ["texture"]
    elif detail == "missing":
        m.pop(draw(st.sampled_from(sorted(m))))
    if draw(st.integers(0, 7)) == 0:
        m["shininess"] = 3
    case.doc["materials"][name] = m
    return f"materials.{name}:{model}:{detail}"


@st.composite
def object_mutation(draw, case: Case) -> str:
    name = draw(st.sampled_from(sorted(case.doc["objects"])))
    obj = case.doc["objects"][name]
    kind = draw(st.sampled_from(["primitive", "transform", "mesh", "material", "smooth"]))
    if kind == "primitive":
        prim = draw(st.sampled_from(["plane", "sphere", "box", "cone"]))
        spec: dict[str, Any] = {"type": prim}
        if prim == "plane":
            spec["size"] = draw(vectors(1e-6, 1e3, 2))
        elif prim == "sphere":
            spec.update(radius=draw(numbers(1e-6, 1e3)),
                        subdivisions=draw(st.one_of(st.integers(0, 3), junk())))
        elif prim == "box":
            spec["size"] = draw(vectors(1e-6, 1e3))
        obj.pop("mesh", None)
        obj["primitive"] = spec
    elif kind == "transform":
        t = draw(st.sampled_from(["scale", "translate", "rotate", "matrix"]))
        value = {"scale": st.one_of(vectors(-2.0, 2.0), st.just([1, -1, 1]),
                                    st.just([1, 0, 1]), st.just([1e-6, 1e-6, 1e-6])),
                 "translate": st.one_of(vectors(-3.0, 3.0), st.just([1e6, 0, 0])),
                 "rotate": vectors(-360.0, 360.0),
                 "matrix": st.one_of(st.just([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0],
                                              [0, 0, 0, 1]]), junk())}[t]
        obj["transform"] = {t: draw(value)}
    elif kind == "mesh":
        shape = draw(st.sampled_from(["closed", "inward", "open", "degenerate",
                                      "missing_vertex", "nan", "cut_short", "empty",
                                      "not_found"]))
        scale = draw(st.sampled_from([0.5, 1e-6, 1e4]))
        offset = draw(st.sampled_from([0.0, 0.0, 1e5]))
        obj.pop("primitive", None)
        obj["mesh"] = f"{name}.obj"
        if shape != "not_found":
            case.files[f"{name}.obj"] = obj_text(shape, scale, offset)
        kind = f"mesh:{shape}:{scale:g}:{offset:g}"
    elif kind == "material":
        obj["material"] = draw(st.sampled_from([*sorted(case.doc["materials"]), "nope"]))
    else:
        obj["smooth"] = draw(st.one_of(st.booleans(), junk()))
    return f"objects.{name}.{kind}"


@st.composite
def light_mutation(draw, case: Case) -> str:
    kind = draw(st.sampled_from(["point", "spot", "directional", "quad", "environment",
                                 "none", "bogus"]))
    light: dict[str, Any] = {"type": kind}
    if kind == "point":
        light.update(position=draw(vectors(-3.0, 3.0)), intensity=draw(colours()))
    elif kind == "spot":
        light.update(position=draw(vectors(-3.0, 3.0)), direction=draw(vectors(-1.0, 1.0)),
                     intensity=draw(colours()), angle=draw(numbers(1.0, 90.0)))
        if draw(st.booleans()):
            light["falloff"] = draw(numbers(0.0, 1.0))
    elif kind == "directional":
        light.update(direction=draw(vectors(-1.0, 1.0)), irradiance=draw(colours()))
    elif kind == "quad":
        light.update(corner=draw(vectors(-1.0, 3.0)), edge_u=draw(vectors(-1.0, 1.0)),
                     edge_v=draw(vectors(-1.0, 1.0)), radiance=draw(colours()))
        if draw(st.booleans()):
            light["samples"] = draw(st.sampled_from([1, 4, 9, 3, 0, -4]))
    elif kind == "environment":
        map_kind = draw(st.sampled_from(["plain", "zeros", "sun", "nan", "negative",
                                         "overflow", "tiny", "not_twice", "png",
                                         "not_found"]))
        height = draw(st.sampled_from([1, 2, 3, 8, 16]))
        name = "env.png" if map_kind == "png" else "env.exr"
        if map_kind == "png":
            case.files[name] = ["texture"]
        elif map_kind != "not_found":
            case.files[name] = ["map", map_kind, height]
        light["file"] = name
        if draw(st.booleans()):
            light["rotation"] = draw(numbers(-720.0, 720.0))
        if draw(st.booleans()):
            light["scale"] = draw(numbers(0.0, 4.0))
        kind = f"environment:{map_kind}:{height}"
    lights = case.doc.setdefault("lights", [])
    how = draw(st.sampled_from(["add", "replace", "replace_all"]))
    if kind == "none":
        case.doc["lights"] = []
    elif how == "add" or not lights:
        lights.append(light)
    elif how == "replace":
        lights[draw(st.integers(0, len(lights) - 1))] = light
    else:
        case.doc["lights"] = [light]
    return f"lights:{kind}:{how}"


@st.composite
def settings_mutation(draw, case: Case) -> str:
    from pipeline import job

    params = job.stages().params
    name = draw(st.sampled_from(sorted(params)))
    default = SETTINGS.get(case.method, {}).get(name, params[name])
    if isinstance(default, bool):
        value = draw(st.one_of(st.booleans(), junk()))
    elif isinstance(default, int):
        value = draw(st.one_of(st.integers(0, max(2 * default, 4)), st.just(-1),
                               st.just(10 ** 12), junk()))
    elif isinstance(default, float):
        value = draw(st.one_of(st.floats(0.0, 2 * default + 1.0), st.just(-1.0),
                               st.just(float("nan")), junk()))
    elif isinstance(default, list):
        value = draw(st.one_of(st.lists(st.integers(0, 16), min_size=0, max_size=4),
                               st.just([]), junk()))
    else:
        value = draw(st.one_of(st.sampled_from(["chunk", "block", "proportional",
                                                "tolerance", "bogus"]), junk()))
    case.doc["settings"][name] = value
    return f"settings.{name}"


@st.composite
def methods_mutation(draw, case: Case) -> str:
    case.doc["methods"] = draw(st.one_of(
        st.lists(st.sampled_from([*METHODS, "bogus"]), min_size=0, max_size=2), junk()))
    return "methods"


@st.composite
def command_mutation(draw, case: Case) -> str:
    option = draw(st.sampled_from(["--size", "--exposure", "--option", "--set",
                                   "--env-rotate"]))
    if option == "--size":
        value = draw(st.sampled_from(["4x4", "7x3", "0x4", "x", "9x99999", "12x8"]))
    elif option == "--exposure":
        value = str(draw(numbers(-8.0, 8.0)))
    elif option == "--option":
        name = draw(st.sampled_from(["max_bounces", "bounce_tolerance", "shadows", "layout",
                                     "budget", "selection", "component", "lambda_blend",
                                     "bogus"]))
        value = f"{name}={draw(st.sampled_from(['0', '2', '-1', '1e-3', 'cpu', 'all', 'x']))}"
    elif option == "--set":
        material = draw(st.sampled_from([*sorted(case.doc['materials']), "nope"]))
        key = draw(st.sampled_from(["gamma", "specular", "albedo", "bogus"]))
        value = f"{material}.{key}={draw(st.sampled_from(['40', '0.1', '-1', 'x', '1e9']))}"
    else:
        value = str(draw(numbers(-720.0, 720.0)))
    case.args += [option, value]
    return f"cli:{option}"


MUTATIONS = (camera_mutation, material_mutation, object_mutation, light_mutation,
             settings_mutation, methods_mutation, command_mutation)


@st.composite
def cases(draw, max_mutations: int = 3) -> Case:
    """A method's tiny scene with up to ``max_mutations`` mutations."""
    case = _base(draw(st.sampled_from(METHODS)), draw(st.integers(4, 8)))
    for _ in range(draw(st.integers(0, max_mutations))):
        family = draw(st.sampled_from(MUTATIONS))
        case.mutations.append(draw(family(case)))
    return case


# ------------------------------------------------------------------------ running


@dataclass
class Outcome:
    """What a case did: ``kind`` ``exit0`` (a finite frame), ``exit2`` (one error line),
    or ``else`` with ``problem`` saying what broke the invariant."""

    kind: str
    returncode: int | None
    message: str
    seconds: float
    problem: str = ""


def write_case(case: Case, folder: Path) -> Path:
    """The case's scene file and its extra files under ``folder``; the scene's path."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    for name, spec in case.files.items():
        if isinstance(spec, str):
            (folder / name).write_text(spec)
        elif spec[0] == "map":
            write_map(folder / name, spec[1], spec[2])
        else:
            Image.new("L", (8, 8), 128).save(folder / name)
    scene = folder / "scene.yaml"
    scene.write_text(yaml.safe_dump(case.doc, sort_keys=False, allow_unicode=True))
    return scene


def _prt(args: list[str], cwd: Path, timeout: float) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PRT_JOBS": "1"}
    return subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def one_error_line(stderr: str) -> str | None:
    """The ``error:`` line when stderr is exactly that (notes and warnings before it
    allowed), else None."""
    lines = [line for line in stderr.strip().splitlines()
             if not line.startswith(("note: ", "warning: "))]
    if len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in stderr:
        return lines[0]
    return None


def run_case(case: Case, folder: Path, timeout: float = CASE_TIMEOUT) -> Outcome:
    """Render the case's frame with ``prt render`` in ``folder`` and check the invariant
    (module docstring)."""
    import time

    from pipeline.images import read_exr

    scene = write_case(case, folder)
    work, out = folder / "w", folder / "frame.exr"
    args = ["render", str(scene), "--method", case.method, "--out", str(out),
            "--workdir", str(work), "-q", *case.args]
    start = time.perf_counter()
    try:
        result = _prt(args, folder, timeout)
    except subprocess.TimeoutExpired:
        return Outcome("else", None, "", timeout, f"no answer in {timeout:.0f} s")
    seconds = time.perf_counter() - start
    if result.returncode == 0:
        if "Traceback" in result.stderr or "RuntimeWarning" in result.stderr:
            return Outcome("else", 0, "", seconds, "exit 0 with a traceback or NumPy "
                           "warning: " + result.stderr.strip()[-300:])
        try:
            rgb = read_exr(out)
        except Exception as exc:  # noqa: BLE001 - any unreadable frame breaks the invariant
            return Outcome("else", 0, "", seconds, f"exit 0 but no readable frame: {exc}")
        if not np.isfinite(rgb).all() or rgb.min() < 0:
            return Outcome("else", 0, "", seconds, "exit 0 with a frame not finite or "
                           "negative")
        kind, message = "exit0", ""
    elif result.returncode == 2 and one_error_line(result.stderr):
        kind, message = "exit2", one_error_line(result.stderr) or ""
    else:
        tail = result.stderr.strip().splitlines()[-3:]
        return Outcome("else", result.returncode, " | ".join(tail), seconds,
                       f"exit {result.returncode} without one error line")
    if work.exists():  # the work directory still answers (and no lock was left)
        status = _prt(["status", str(scene), "--workdir", str(work), "--json"], folder, 120)
        if status.returncode not in (0, 2) or "Traceback" in status.stderr or \
                (status.returncode == 2 and not one_error_line(status.stderr)):
            return Outcome("else", result.returncode, message, seconds,
                           "prt status failed afterwards: " + status.stderr.strip()[-300:])
    return Outcome(kind, result.returncode, message, seconds)


def finite(x: Any) -> Any:
    """``x`` with non-finite floats as strings (for JSON records)."""
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [finite(v) for v in x]
    return x


def record(case: Case, outcome: Outcome) -> str:
    """One JSON line for a case and its outcome."""
    return json.dumps(finite({**case.describe(), "outcome": outcome.__dict__}))
