"""Scene files: YAML -> a validated, immutable scene model.

A scene file (format ``prt-scene/1``) holds these top-level sections::

    format: prt-scene/1
    name: cornell_box
    camera:   {position, look_at, up, fov (vertical, degrees), width, height}
    materials: {NAME: {model, albedo, ...model parameters}}
               # glossy models: specular (ρs, scalar or RGB), gamma, gamma_range [min, max]
               # (the PCA basis covers it), optional pca_tolerance; ward_anisotropic:
               # alpha_ratio (αy/αx); lafortune: cxy, cz; cook_torrance and
               # ashikhmin_shirley: f0 or ior (see pipeline/math/brdf.py)
    objects:   {NAME: {mesh: PATH | primitive: {...}, transform: {...}, material: NAME}}
    lights:    [{type: point|spot|directional|quad|environment, ...}]
    settings:  {PARAM.KEY: value}   # overrides of stage parameter defaults

Units: lengths in scene units (the Cornell box uses millimetres); angles in degrees;
point/spot intensity in W/sr, directional irradiance in W/m², area-light and environment
radiance in W/(m² sr), all linear RGB. Paths resolve relative to the scene file; the
prefix ``${PRT_DATA}`` names the shared data folder (see :func:`shared_data_dir`).

Every problem is reported as a :class:`~pipeline.errors.PrtError` naming the file, the key
path and what was expected. :meth:`Scene.section` gives the canonical JSON value of a dotted
section path, which is what stage keys hash.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import PrtError
from pipeline.keys import file_hash

SCENE_FORMAT = "prt-scene/1"

MATERIAL_MODELS = (
    "lambert",
    "blinn_phong",
    "ward",
    "ward_duer",
    "ward_anisotropic",
    "lafortune",
    "cook_torrance",
    "ashikhmin_shirley",
)
# Parameters each model accepts beyond the common ``model`` and ``albedo``.
_GLOSSY_KEYS = {"specular", "gamma", "gamma_range", "pca_tolerance"}
MODEL_KEYS: dict[str, set[str]] = {
    "lambert": set(),
    "blinn_phong": _GLOSSY_KEYS,
    "ward": _GLOSSY_KEYS,
    "ward_duer": _GLOSSY_KEYS,
    "ward_anisotropic": _GLOSSY_KEYS | {"alpha_ratio"},
    "lafortune": _GLOSSY_KEYS | {"cxy", "cz"},
    "cook_torrance": _GLOSSY_KEYS | {"f0", "ior"},
    "ashikhmin_shirley": _GLOSSY_KEYS | {"f0", "ior"},
}
LIGHT_TYPES = ("point", "spot", "directional", "quad", "environment")
PRIMITIVES = ("plane", "sphere", "box")


def shared_data_dir() -> Path | None:
    """The shared data folder: ``$PRT_DATA``, else the first ``shared/data`` found beside
    the working directory or the package checkout, walking up. ``None`` when absent."""
    env = os.environ.get("PRT_DATA")
    if env:
        return Path(env)
    for start in (Path.cwd(), Path(__file__).resolve().parent):
        for folder in (start, *start.parents):
            candidate = folder / "shared" / "data"
            if candidate.is_dir():
                return candidate
    return None


@dataclass(frozen=True)
class Camera:
    """Pinhole camera. ``fov`` is the vertical field of view in degrees; the image is
    ``width`` × ``height`` pixels, row 0 at the top."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float
    width: int
    height: int


@dataclass(frozen=True)
class Material:
    """One named material: ``model`` from :data:`MATERIAL_MODELS`, diffuse RGB ``albedo``
    and the model's parameters (kept as given; the BRDF module interprets them)."""

    name: str
    model: str
    albedo: tuple[float, float, float]
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SceneObject:
    """One named object: a mesh file or a primitive, a 4×4 object-to-world matrix
    (row-major, column vectors) and a material name."""

    name: str
    mesh: Path | None
    primitive: dict[str, Any] | None
    transform: tuple[tuple[float, ...], ...]
    material: str


@dataclass(frozen=True)
class Light:
    """One light; ``params`` holds the type's fields as validated (see module docstring)."""

    type: str
    params: dict[str, Any]


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``raw`` keeps the canonical, path-resolved dictionary that
    :meth:`section` reads from."""

    path: Path
    name: str
    camera: Camera
    materials: dict[str, Material]
    objects: dict[str, SceneObject]
    lights: tuple[Light, ...]
    settings: dict[str, Any]
    raw: dict[str, Any]
    methods: tuple[str, ...] | None = None

    def with_image_size(self, width: int, height: int) -> Scene:
        """The same scene rendered at ``width`` × ``height`` pixels."""
        if width < 1 or height < 1:
            raise PrtError(self.path, f"image size {width}x{height}: width and height must "
                           "be positive")
        camera = replace(self.camera, width=width, height=height)
        raw = {**self.raw, "camera": {**self.raw["camera"], "width": width, "height": height}}
        return replace(self, camera=camera, raw=raw)

    def with_settings(self, overrides: dict[str, Any]) -> Scene:
        """The same scene with stage-parameter ``overrides`` added to its settings."""
        settings = {**self.settings, **overrides}
        return replace(self, settings=settings, raw={**self.raw, "settings": settings})

    def section(self, dotted: str) -> Any:
        """The canonical value at a dotted path (``camera``, ``objects.floor.material``,
        ``materials.white``). File paths (``mesh``, ``file``) are replaced by the SHA-256
        of the file's content: editing the file changes the value, moving the scene and
        its files elsewhere does not. Missing paths give ``None``."""
        node: Any = self.raw
        parts = dotted.split(".")
        for part in parts:
            if not isinstance(node, dict) or part not in node:
                return None
            node = node[part]
        if parts[-1] in ("mesh", "file") and isinstance(node, str):
            return {"sha256": file_hash(Path(node))}
        return _with_file_hashes(node)


def _with_file_hashes(node: Any) -> Any:
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if key in ("mesh", "file") and isinstance(value, str):
                out[key] = {"sha256": file_hash(Path(value))}
            else:
                out[key] = _with_file_hashes(value)
        return out
    if isinstance(node, list):
        return [_with_file_hashes(v) for v in node]
    return node


# --------------------------------------------------------------------------- validation


class _Checker:
    """Small typed readers that raise PrtError naming the file and key path."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> PrtError:
        return PrtError(self.path, f"{where}: {problem}" if where else problem)

    def mapping(self, value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"expected a mapping, found {type(value).__name__}")
        return value

    def keys(self, value: dict, where: str, required: set[str], optional: set[str]) -> None:
        unknown = sorted(set(value) - required - optional)
        if unknown:
            allowed = ", ".join(sorted(required | optional))
            raise self.fail(where, f"unknown key '{unknown[0]}' (allowed: {allowed})")
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(where, f"missing required key '{missing[0]}'")

    def number(self, value: Any, where: str, lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(where, f"expected a number, found {value!r}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(where, f"expected a finite number, found {value!r}")
        if x < lo or x > hi or (lo_open and x == lo):
            bound = f"> {lo:g}" if lo_open else f"in [{lo:g}, {hi:g}]"
            raise self.fail(where, f"expected a number {bound}, found {value!r}")
        return x

    def integer(self, value: Any, where: str, lo: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(where, f"expected an integer, found {value!r}")
        if value < lo:
            raise self.fail(where, f"expected an integer >= {lo}, found {value}")
        return value

    def vector(self, value: Any, where: str, n: int = 3, lo: float = -math.inf,
               hi: float = math.inf) -> tuple[float, ...]:
        if isinstance(value, int | float) and not isinstance(value, bool) and n == 3:
            value = [value] * 3
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.fail(where, f"expected a list of {n} numbers, found {value!r}")
        return tuple(self.number(v, f"{where}[{i}]", lo, hi) for i, v in enumerate(value))

    def direction(self, value: Any, where: str) -> tuple[float, ...]:
        v = self.vector(value, where)
        if math.hypot(*v) == 0.0:
            raise self.fail(where, "expected a non-zero direction")
        return v

    def choice(self, value: Any, where: str, options: tuple[str, ...]) -> str:
        if value not in options:
            raise self.fail(where, f"unknown value {value!r} (expected one of: "
                            f"{', '.join(options)})")
        return value

    def file(self, value: Any, where: str) -> Path:
        if not isinstance(value, str) or not value:
            raise self.fail(where, f"expected a file path, found {value!r}")
        if "${PRT_DATA}" in value:
            data = shared_data_dir()
            if data is None:
                raise self.fail(where, f"{value}: the shared data folder was not found "
                                "(set PRT_DATA to the folder holding meshes/ and envmaps/)")
            value = value.replace("${PRT_DATA}", str(data))
        resolved = (self.path.parent / value).resolve()
        if not resolved.is_file():
            raise self.fail(where, f"file not found: {resolved}")
        return resolved


def _transform_matrix(chk: _Checker, spec: Any, where: str) -> tuple[tuple[float, ...], ...]:
    """4×4 matrix from ``{matrix}`` or ``{translate, rotate, scale}`` (applied as
    scale, then rotations about x, y, z in degrees, then translation)."""
    import numpy as np

    if spec is None:
        return tuple(tuple(r) for r in np.eye(4).tolist())
    spec = chk.mapping(spec, where)
    chk.keys(spec, where, set(), {"matrix", "translate", "rotate", "scale"})
    if "matrix" in spec:
        if len(spec) > 1:
            raise chk.fail(where, "'matrix' cannot be combined with translate/rotate/scale")
        rows = spec["matrix"]
        if not isinstance(rows, list) or len(rows) != 4:
            raise chk.fail(f"{where}.matrix", "expected 4 rows of 4 numbers")
        m = np.array([chk.vector(r, f"{where}.matrix[{i}]", 4) for i, r in enumerate(rows)])
    else:
        t = chk.vector(spec.get("translate", [0, 0, 0]), f"{where}.translate")
        r = chk.vector(spec.get("rotate", [0, 0, 0]), f"{where}.rotate")
        s = chk.vector(spec.get("scale", 1.0), f"{where}.scale")
        if min(abs(x) for x in s) == 0.0:
            raise chk.fail(f"{where}.scale", "scale must be non-zero")
        m = np.diag([*s, 1.0])
        for axis, deg in enumerate(r):
            c, si = math.cos(math.radians(deg)), math.sin(math.radians(deg))
            rot = np.eye(4)
            i, j = [(1, 2), (2, 0), (0, 1)][axis]
            rot[i, i], rot[i, j], rot[j, i], rot[j, j] = c, -si, si, c
            m = rot @ m
        m[:3, 3] += t
    if abs(np.linalg.det(m[:3, :3])) < 1e-12:
        raise chk.fail(where, "transform is singular")
    return tuple(tuple(float(x) for x in row) for row in m)


def _material(chk: _Checker, name: str, spec: Any) -> tuple[Material, dict]:
    where = f"materials.{name}"
    spec = chk.mapping(spec, where)
    model = chk.choice(spec.get("model"), f"{where}.model", MATERIAL_MODELS)
    chk.keys(spec, where, {"model"}, {"albedo"} | MODEL_KEYS[model])
    albedo = chk.vector(spec.get("albedo", [0.8, 0.8, 0.8]), f"{where}.albedo", 3, 0.0, 1.0)
    params: dict[str, Any] = {}
    if model != "lambert":
        for key in ("gamma", "gamma_range"):
            if key not in spec:
                raise chk.fail(where, f"missing required key '{key}' for model {model}")
        lo, hi = chk.vector(spec["gamma_range"], f"{where}.gamma_range", 2, 0.0)
        if not 0 < lo < hi:
            raise chk.fail(f"{where}.gamma_range", f"expected 0 < min < max, found [{lo}, {hi}]")
        gamma = chk.number(spec["gamma"], f"{where}.gamma", lo, hi)
        params = {"gamma": gamma, "gamma_range": [lo, hi],
                  "specular": list(chk.vector(spec.get("specular", 0.5), f"{where}.specular",
                                              3, 0.0, 1.0))}
        bounds = {"alpha_ratio": (1e-3, 1e3), "cxy": (-1e3, 1e3), "cz": (-1e3, 1e3),
                  "f0": (0.0, 1.0), "ior": (1.0, 10.0), "pca_tolerance": (1e-9, 0.5)}
        for key in sorted(set(spec) & set(bounds)):
            params[key] = chk.number(spec[key], f"{where}.{key}", *bounds[key])
        if "f0" in params and "ior" in params:
            raise chk.fail(where, "give either f0 or ior (F0 = ((ior-1)/(ior+1))^2), not both")
        if model == "lafortune" and max(abs(params.get("cxy", -1.0)),
                                        abs(params.get("cz", 1.0))) == 0.0:
            raise chk.fail(where, "cxy and cz cannot both be zero")
    canonical = {"model": model, "albedo": list(albedo), **params}
    return Material(name, model, albedo, params), canonical


def _object(chk: _Checker, name: str, spec: Any, materials: dict) -> tuple[SceneObject, dict]:
    where = f"objects.{name}"
    spec = chk.mapping(spec, where)
    chk.keys(spec, where, {"material"}, {"mesh", "primitive", "transform"})
    if ("mesh" in spec) == ("primitive" in spec):
        raise chk.fail(where, "expected exactly one of 'mesh' or 'primitive'")
    material = spec["material"]
    if material not in materials:
        raise chk.fail(f"{where}.material", f"unknown material {material!r} (defined: "
                       f"{', '.join(materials) or 'none'})")
    mesh = primitive = None
    canonical: dict[str, Any] = {}
    if "mesh" in spec:
        mesh = chk.file(spec["mesh"], f"{where}.mesh")
        canonical["mesh"] = str(mesh)
    else:
        primitive = _primitive(chk, spec["primitive"], f"{where}.primitive")
        canonical["primitive"] = primitive
    transform = _transform_matrix(chk, spec.get("transform"), f"{where}.transform")
    canonical["transform"] = [list(r) for r in transform]
    canonical["material"] = material
    return SceneObject(name, mesh, primitive, transform, material), canonical


def _primitive(chk: _Checker, spec: Any, where: str) -> dict[str, Any]:
    spec = chk.mapping(spec, where)
    kind = chk.choice(spec.get("type"), f"{where}.type", PRIMITIVES)
    if kind == "plane":
        chk.keys(spec, where, {"type"}, {"size"})
        return {"type": kind, "size": list(chk.vector(spec.get("size", [1, 1]), f"{where}.size",
                                                      2, 0.0))}
    if kind == "sphere":
        chk.keys(spec, where, {"type"}, {"radius", "subdivisions"})
        return {"type": kind,
                "radius": chk.number(spec.get("radius", 1.0), f"{where}.radius", 0.0,
                                     lo_open=True),
                "subdivisions": chk.integer(spec.get("subdivisions", 3),
                                            f"{where}.subdivisions", 0)}
    chk.keys(spec, where, {"type"}, {"size"})
    return {"type": kind, "size": list(chk.vector(spec.get("size", [1, 1, 1]), f"{where}.size",
                                                  3, 0.0))}


_LIGHT_KEYS: dict[str, tuple[set[str], set[str]]] = {
    "point": ({"position", "intensity"}, set()),
    "spot": ({"position", "direction", "intensity", "angle"}, {"falloff"}),
    "directional": ({"direction", "irradiance"}, set()),
    "quad": ({"corner", "edge_u", "edge_v", "radiance"}, {"object", "samples"}),
    "environment": ({"file"}, {"rotation", "scale"}),
}


def _light(chk: _Checker, index: int, spec: Any, objects: dict) -> tuple[Light, dict]:
    where = f"lights[{index}]"
    spec = chk.mapping(spec, where)
    kind = chk.choice(spec.get("type"), f"{where}.type", LIGHT_TYPES)
    required, optional = _LIGHT_KEYS[kind]
    chk.keys(spec, where, required | {"type"}, optional)
    p: dict[str, Any] = {}
    for key in sorted(set(spec) - {"type"}):
        value, at = spec[key], f"{where}.{key}"
        if key in ("position", "corner", "edge_u", "edge_v"):
            p[key] = list(chk.vector(value, at))
        elif key == "direction":
            p[key] = list(chk.direction(value, at))
        elif key in ("intensity", "irradiance", "radiance"):
            p[key] = list(chk.vector(value, at, 3, 0.0))
        elif key == "angle":
            p[key] = chk.number(value, at, 0.0, 90.0, lo_open=True)
        elif key == "falloff":
            p[key] = chk.number(value, at, 0.0, 1.0)
        elif key == "samples":
            p[key] = chk.integer(value, at, 1)
            if math.isqrt(p[key]) ** 2 != p[key]:
                raise chk.fail(at, f"expected a square number (4, 9, 16, ...), found {value}")
        elif key == "object":
            if value not in objects:
                raise chk.fail(at, f"unknown object {value!r}")
            p[key] = value
        elif key == "file":
            p[key] = str(chk.file(value, at))
        elif key == "rotation":
            p[key] = chk.number(value, at)
        elif key == "scale":
            p[key] = chk.number(value, at, 0.0)
    if kind == "quad":
        cross = _cross(p["edge_u"], p["edge_v"])
        if math.hypot(*cross) == 0.0:
            raise chk.fail(where, "edge_u and edge_v are parallel or zero (the quad has no area)")
    return Light(kind, p), {"type": kind, **p}


def _cross(a: list[float], b: list[float]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file; raise PrtError naming the file and key on problems."""
    path = Path(path).resolve()
    if not path.is_file():
        raise PrtError(path, "scene file not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise PrtError(path, f"malformed YAML: {where}{problem}") from None
    except UnicodeDecodeError:
        raise PrtError(path, "not a text file") from None
    chk = _Checker(path)
    doc = chk.mapping(doc, "")
    chk.keys(doc, "", {"format", "name", "camera", "objects"},
             {"materials", "lights", "settings", "methods"})
    if doc["format"] != SCENE_FORMAT:
        raise chk.fail("format", f"expected {SCENE_FORMAT!r}, found {doc['format']!r}")
    name = doc["name"]
    if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
        raise chk.fail("name", f"expected a name of letters, digits, '_' or '-', found {name!r}")

    cam = chk.mapping(doc["camera"], "camera")
    chk.keys(cam, "camera", {"position", "look_at", "fov", "width", "height"}, {"up"})
    camera = Camera(
        position=chk.vector(cam["position"], "camera.position"),
        look_at=chk.vector(cam["look_at"], "camera.look_at"),
        up=chk.direction(cam.get("up", [0, 1, 0]), "camera.up"),
        fov=chk.number(cam["fov"], "camera.fov", 0.0, 180.0, lo_open=True),
        width=chk.integer(cam["width"], "camera.width", 1),
        height=chk.integer(cam["height"], "camera.height", 1),
    )
    if camera.position == camera.look_at:
        raise chk.fail("camera.look_at", "must differ from camera.position")

    materials, raw_materials = {}, {}
    for mname, mspec in chk.mapping(doc.get("materials") or {}, "materials").items():
        materials[mname], raw_materials[mname] = _material(chk, str(mname), mspec)
    objects, raw_objects = {}, {}
    objs = chk.mapping(doc["objects"], "objects")
    if not objs:
        raise chk.fail("objects", "the scene has no objects")
    for oname, ospec in objs.items():
        objects[oname], raw_objects[oname] = _object(chk, str(oname), ospec, materials)
    lights, raw_lights = [], []
    light_list = doc.get("lights") or []
    if not isinstance(light_list, list):
        raise chk.fail("lights", "expected a list of lights")
    for i, lspec in enumerate(light_list):
        light, raw = _light(chk, i, lspec, objects)
        lights.append(light)
        raw_lights.append(raw)
    settings = chk.mapping(doc.get("settings") or {}, "settings")

    raw = {
        "camera": {"position": list(camera.position), "look_at": list(camera.look_at),
                   "up": list(camera.up), "fov": camera.fov,
                   "width": camera.width, "height": camera.height},
        "materials": raw_materials,
        "objects": raw_objects,
        "lights": raw_lights,
        "settings": dict(settings),
        "material_table": list(materials),
    }
    methods = doc.get("methods")
    if methods is not None and (not isinstance(methods, list)
                                or not all(isinstance(m, str) for m in methods)):
        raise chk.fail("methods", "expected a list of method names")
    return Scene(path, name, camera, materials, objects, tuple(lights), dict(settings), raw,
                 None if methods is None else tuple(methods))


EDITABLE_KEYS = ("gamma", "specular", "albedo")


def with_material_edits(scene: Scene, edits: list[str]) -> Scene:
    """The scene with run-time material edits ``NAME.KEY=VALUE`` applied: NAME a material
    or an object (meaning its material), KEY one of :data:`EDITABLE_KEYS`, VALUE a number
    or ``r,g,b``. Each edited material is validated as in the file; γ must lie in the
    material's gamma_range, the range its PCA basis was baked over (no extrapolation)."""
    chk = _Checker(scene.path)
    materials, raw = dict(scene.materials), dict(scene.raw["materials"])
    for edit in edits:
        target, eq, value_text = edit.partition("=")
        name, dot, key = target.rpartition(".")
        if not eq or not dot:
            raise chk.fail(f"--set {edit}", "expected NAME.KEY=VALUE, e.g. floor.gamma=40")
        if name in scene.objects:
            name = scene.objects[name].material
        if name not in materials:
            raise chk.fail(f"--set {edit}", f"no material or object named {name!r}")
        if key not in EDITABLE_KEYS:
            raise chk.fail(f"--set {edit}", f"cannot edit {key!r} at run time (editable: "
                           f"{', '.join(EDITABLE_KEYS)})")
        try:
            numbers = [float(v) for v in value_text.split(",")]
        except ValueError:
            raise chk.fail(f"--set {edit}", f"expected a number or r,g,b, found "
                           f"{value_text!r}") from None
        spec = dict(raw[name])
        if key != "albedo" and materials[name].model == "lambert":
            raise chk.fail(f"--set {edit}", f"material {name!r} is Lambertian; it has "
                           f"no {key}")
        if key == "gamma":
            lo, hi = spec["gamma_range"]
            if len(numbers) != 1 or not lo <= numbers[0] <= hi:
                raise chk.fail(f"--set {edit}", f"gamma {value_text} is outside the baked "
                               f"PCA range [{lo:g}, {hi:g}] of material {name!r}; widen its "
                               "gamma_range in the scene file and re-bake")
        spec[key] = numbers[0] if len(numbers) == 1 else numbers
        materials[name], raw[name] = _material(chk, name, spec)
    return replace(scene, materials=materials, raw={**scene.raw, "materials": raw})


def with_light_offset(scene: Scene, index: int, offset: tuple[float, float, float]) -> Scene:
    """The scene with light ``index`` moved by ``offset`` (scene units, world frame): a
    point or spot light's position, a quad light's corner. Directional and environment
    lights have no position; moving them, or to a non-finite place, is an error."""
    chk = _Checker(scene.path)
    light = scene.lights[index]
    key = {"point": "position", "spot": "position", "quad": "corner"}.get(light.type)
    if key is None:
        raise chk.fail(f"lights[{index}]", f"a {light.type} light has no position to move")
    moved = [float(a) + float(b) for a, b in zip(light.params[key], offset, strict=True)]
    if not all(math.isfinite(v) for v in moved):
        raise chk.fail(f"lights[{index}].{key}", f"moved to a non-finite position {moved}")
    lights = list(scene.lights)
    lights[index] = Light(light.type, {**light.params, key: moved})
    raw = list(scene.raw["lights"])
    raw[index] = {**raw[index], key: moved}
    return replace(scene, lights=tuple(lights), raw={**scene.raw, "lights": raw})


def default_scene_path() -> Path:
    """The embedded default scene (the Cornell box with a glossy floor)."""
    checkout = Path(__file__).resolve().parent.parent / "scenes" / "cornell_box.yaml"
    if checkout.is_file():
        return checkout
    from importlib.resources import files

    return Path(str(files("pipeline.scenes") / "cornell_box.yaml"))
