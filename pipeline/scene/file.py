"""The scene file format ``prt-scene/1`` as pydantic v2 models, which produce the scene model.

A scene file holds these top-level keys::

    format: prt-scene/1
    name: cornell_box
    camera:   {position, look_at, up, fov (vertical, degrees), width, height}
    materials: {NAME: {model, albedo, ...model parameters}}
    objects:   {NAME: {mesh: PATH | primitive: {...}, transform: {...}, material: NAME,
                        smooth: BOOL, subdivide: N}}
    lights:    [{type: point|spot|directional|quad|environment, ...}]
    settings:  {PARAM.KEY: value}   # overrides of stage parameter defaults
    methods:   [NAME, ...]          # optional: the rendering methods the scene is baked for

Each material model's parameters are declared in
:data:`pipeline.math.brdf.MATERIAL_PARAMETERS` (glossy models: ``specular`` ρs, ``gamma``,
and method d2i's optional ``gamma_range`` and ``pca_tolerance``; ward_anisotropic:
``alpha_ratio``; lafortune: ``cxy``, ``cz``; cook_torrance and ashikhmin_shirley: ``f0``
or ``ior``); the material models here are generated from that table.

Units: lengths in scene units (the Cornell box uses millimetres); angles in degrees;
point/spot intensity in W/sr, directional irradiance in W/m², area-light and environment
radiance in W/(m² sr), all linear RGB. Paths resolve relative to the scene file; the
prefix ``${PRT_DATA}`` names the shared data folder (see :func:`shared_data_dir`).

Unknown keys are errors (``extra="forbid"``). A problem is reported as one
``PrtError(FILE, "key.path: problem")``, from the first error pydantic reports: the
error's location becomes the dotted key path of the file (list items as ``[i]``, e.g.
``lights[0].radiance``, ``objects.floor.transform.scale``), and the leaf validators here
raise their problem text as it should read (``expected a number, found 'x'``; any other
pydantic error keeps pydantic's message). Each
mapping reports unknown keys first, then missing ones, then its values in the order
its model declares them, so the first error is the first problem met reading the file.
"""

from __future__ import annotations

import math
import operator
from functools import reduce
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    create_model,
    model_validator,
)
from pydantic_core import PydanticCustomError

from pipeline.errors import PrtError
from pipeline.images import read_environment, read_texture
from pipeline.math.brdf import MATERIAL_PARAMETERS, SceneParam, specular_albedo_bound
from pipeline.math.textures import WRAPS
from pipeline.scene.model import (
    MAX_IMAGE_SIDE,
    Blend,
    Bump,
    Camera,
    Light,
    Material,
    Scene,
    SceneObject,
    TextureMap,
    shared_data_dir,
)
from pipeline.yamlfile import load_yaml

SCENE_FORMAT = "prt-scene/1"
MATERIAL_MODELS = tuple(MATERIAL_PARAMETERS)
LIGHT_TYPES = ("point", "spot", "directional", "quad", "environment")
PRIMITIVES = ("plane", "sphere", "box")

Vector = tuple[float, ...]

# --------------------------------------------------------------------------- problems


def _problem(message: str, at: str = "") -> PydanticCustomError:
    """A validation error that reads ``message``; ``at`` extends the error's key path
    below the value being validated (``[1]``, ``.look_at``)."""
    return PydanticCustomError("prt_scene", "{problem}", {"problem": message, "at": at})


def _key_path(doc: Any, loc: tuple[str | int, ...]) -> str:
    """The dotted key path of a pydantic error location within ``doc``: keys as
    ``.key``, list positions as ``[i]``. Location parts that name no key of the document
    (the tags of discriminated unions) are left out."""
    path, node = "", doc
    for part in loc:
        if isinstance(part, int):
            path += f"[{part}]"
            node = node[part] if isinstance(node, list) and part < len(node) else None
            continue
        keys = {str(k): k for k in node} if isinstance(node, dict) else {}
        if part in keys:
            path += f".{part}"
            node = node[keys[part]]
    return path.lstrip(".")


def _validated(adapter: TypeAdapter, value: Any, file: Path, context: dict[str, Any],
               where: str = "") -> Any:
    """``value`` validated by ``adapter``; its first error as a PrtError naming ``file``
    and the key path (below ``where``)."""
    try:
        return adapter.validate_python(value, context=context)
    except ValidationError as exc:
        error = exc.errors(include_url=False)[0]
        ctx = error.get("ctx") or {}
        problem = ctx["problem"] if error["type"] == "prt_scene" else error["msg"]
        key = ".".join(p for p in (where, _key_path(value, error["loc"])) if p)
        key += ctx.get("at", "")
        raise PrtError(file, f"{key}: {problem}" if key else problem) from None


# ----------------------------------------------------------------------- leaf values
# Plain functions that check one value, return it in canonical form and raise _problem.


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _number(value: Any, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
            at: str = "", hi_open: bool = False) -> float:
    """A finite number in ``[lo, hi]`` (open at ``lo`` or ``hi`` when ``lo_open``,
    ``hi_open``), as float."""
    if not _is_number(value):
        raise _problem(f"expected a number, found {value!r}", at)
    x = float(value)
    if not math.isfinite(x):
        raise _problem(f"expected a finite number, found {value!r}", at)
    if x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi):
        bound = (f"> {lo:g}" if lo_open and math.isinf(hi) else
                 f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}")
        raise _problem(f"expected a number {bound}, found {value!r}", at)
    return x


def _integer(value: Any, lo: int, hi: int | None = None, why: str = "") -> int:
    """An integer >= ``lo`` (and <= ``hi``, ``why`` saying why that limit)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise _problem(f"expected an integer, found {value!r}")
    if value < lo:
        raise _problem(f"expected an integer >= {lo}, found {value}")
    if hi is not None and value > hi:
        raise _problem(f"expected an integer <= {hi}{why}, found {value}")
    return value


def _image_side(value: Any) -> int:
    """An image width or height: 1 to MAX_IMAGE_SIDE pixels."""
    return _integer(value, 1, MAX_IMAGE_SIDE, " (the largest image side prt renders)")


def _vector(value: Any, n: int = 3, lo: float = -math.inf, hi: float = math.inf,
            at: str = "") -> Vector:
    """``n`` numbers in ``[lo, hi]``; for ``n`` = 3 one number stands for three equal."""
    if _is_number(value) and n == 3:
        value = [value] * 3
    if not isinstance(value, list | tuple) or len(value) != n:
        raise _problem(f"expected a list of {n} numbers, found {value!r}", at)
    return tuple(_number(v, lo, hi, at=f"{at}[{i}]") for i, v in enumerate(value))


def _direction(value: Any) -> Vector:
    """A non-zero 3-vector."""
    v = _vector(value)
    if math.hypot(*v) == 0.0:
        raise _problem("expected a non-zero direction")
    return v


def _range(value: Any, lo: float, hi: float) -> Vector:
    """``[min, max]`` with each in ``[lo, hi]`` and ``lo < min < max``."""
    a, b = _vector(value, 2, lo, hi)
    if not lo < a < b:
        raise _problem(f"expected {lo:g} < min < max, found [{a}, {b}]")
    return a, b


def _file(value: Any, info: ValidationInfo) -> Path:
    """An existing file, relative to the scene file (context ``path``) or under
    ``${PRT_DATA}``, resolved."""
    if not isinstance(value, str) or not value:
        raise _problem(f"expected a file path, found {value!r}")
    if "${PRT_DATA}" in value:
        data = shared_data_dir()
        if data is None:
            raise _problem(f"{value}: the shared data folder was not found (set PRT_DATA to "
                           "the folder holding meshes/ and envmaps/)")
        value = value.replace("${PRT_DATA}", str(data))
    resolved = (info.context["path"].parent / value).resolve()
    if not resolved.is_file():
        raise _problem(f"file not found: {resolved}")
    return resolved


def _format(value: Any) -> str:
    if value != SCENE_FORMAT:
        raise _problem(f"expected {SCENE_FORMAT!r}, found {value!r}")
    return value


def _scene_name(value: Any) -> str:
    if not isinstance(value, str) or not value.replace("_", "").replace("-", "").isalnum():
        raise _problem(f"expected a name of letters, digits, '_' or '-', found {value!r}")
    return value


def _material_name(value: Any, info: ValidationInfo) -> str:
    """The name of a material of the scene (context ``materials``; absent when one
    material's edited copy is re-validated, whose names were checked with the file)."""
    defined = info.context.get("materials")
    if defined is None:
        return value
    if value not in defined:
        raise _problem(f"unknown material {value!r} (defined: {', '.join(defined) or 'none'})")
    return value


def _object_name(value: Any, info: ValidationInfo) -> str:
    """The name of an object of the scene (context ``objects``)."""
    if value not in info.context["objects"]:
        raise _problem(f"unknown object {value!r}")
    return value


def _square_count(value: Any) -> int:
    """A positive square integer (a stratification grid m × m)."""
    n = _integer(value, 1)
    if math.isqrt(n) ** 2 != n:
        raise _problem(f"expected a square number (4, 9, 16, ...), found {value}")
    return n


def _mapping(value: Any) -> dict[str, Any]:
    """A mapping, empty when the key is given without a value; names as strings."""
    value = value or {}
    if not isinstance(value, dict):
        raise _problem(f"expected a mapping, found {type(value).__name__}")
    return {str(k): v for k, v in value.items()}


def _objects(value: Any) -> dict[str, Any]:
    """The objects mapping: at least one object."""
    if not isinstance(value, dict):
        raise _problem(f"expected a mapping, found {type(value).__name__}")
    if not value:
        raise _problem("the scene has no objects")
    return _mapping(value)


def _lights(value: Any) -> list[Any]:
    """The light list, empty when absent."""
    value = value or []
    if not isinstance(value, list):
        raise _problem("expected a list of lights")
    return value


def _methods(value: Any) -> tuple[str, ...]:
    """Method names (not checked against a registry here)."""
    if not isinstance(value, list) or not value:
        raise _problem(f"expected a list of method names, found {value!r}")
    for i, name in enumerate(value):
        if not isinstance(name, str) or not name:
            raise _problem(f"expected a method name, found {name!r}", f"[{i}]")
    return tuple(value)


def _tagged(key: str, options: tuple[str, ...]) -> BeforeValidator:
    """Checks what a discriminated union dispatches on: a mapping whose ``key`` is one of
    ``options``."""
    def check(value: Any) -> Any:
        if not isinstance(value, dict):
            raise _problem(f"expected a mapping, found {type(value).__name__}")
        if value.get(key) not in options:
            raise _problem(f"unknown value {value.get(key)!r} (expected one of: "
                           f"{', '.join(options)})", f".{key}")
        return value
    return BeforeValidator(check)


# Field types of the sections below.
Point = Annotated[Vector, PlainValidator(_vector)]
Direction = Annotated[Vector, PlainValidator(_direction)]
Colour = Annotated[Vector, PlainValidator(lambda v: _vector(v, 3, 0.0))]
File = Annotated[Path, PlainValidator(_file)]


def _union(models: tuple[type[BaseModel], ...], tag: str, options: tuple[str, ...]) -> Any:
    """A union of ``models`` dispatched on their ``tag`` field, one of ``options``."""
    return Annotated[reduce(operator.or_, models), Field(discriminator=tag),
                     _tagged(tag, options)]


# --------------------------------------------------------------------------- sections


class _Section(BaseModel):
    """A mapping of the scene file with the keys of its fields. A non-mapping, unknown
    keys, missing required keys and a wrong combination of keys are reported before any
    value is checked."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _keys(cls, value: Any) -> Any:
        if not isinstance(value, dict):
            raise _problem(f"expected a mapping, found {type(value).__name__}")
        allowed = set(cls.model_fields)
        unknown = sorted(map(str, set(value) - allowed))
        if unknown:
            raise _problem(f"unknown key '{unknown[0]}' (allowed: {', '.join(sorted(allowed))})")
        missing = sorted(k for k, f in cls.model_fields.items()
                         if f.is_required() and k not in value)
        if missing:
            raise _problem(cls._missing(missing[0], value))
        problem = cls._combination(value)
        if problem:
            raise _problem(problem)
        return value

    @classmethod
    def _missing(cls, key: str, value: dict[str, Any]) -> str:
        """The problem when the required ``key`` is absent from ``value``."""
        return f"missing required key '{key}'"

    @classmethod
    def _combination(cls, value: dict[str, Any]) -> str | None:
        """The problem with the combination of keys given in ``value``, if any."""
        return None

    def given(self) -> dict[str, Any]:
        """The keys given in the file (less the union tag) with their canonical values
        (vectors as lists), in field order."""
        return {k: _plain(getattr(self, k)) for k in type(self).model_fields
                if k in self.model_fields_set and k not in ("type", "model")}


def _plain(value: Any) -> Any:
    """Vectors (tuples) as lists, as the canonical dictionary holds them."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


class _CameraFile(_Section):
    """``camera``: a pinhole camera."""

    position: Point
    look_at: Point
    up: Direction = (0.0, 1.0, 0.0)
    fov: Annotated[float, PlainValidator(lambda v: _number(v, 0.0, 180.0, lo_open=True,
                                                          hi_open=True))]
    width: Annotated[int, PlainValidator(_image_side)]
    height: Annotated[int, PlainValidator(_image_side)]

    @model_validator(mode="after")
    def _looks_somewhere(self) -> _CameraFile:
        if self.position == self.look_at:
            raise _problem("must differ from camera.position", ".look_at")
        with np.errstate(over="ignore"):
            forward = np.subtract(self.look_at, self.position)
        if not np.isfinite(forward).all():
            raise _problem("too far from camera.position (their difference overflows)",
                           ".look_at")
        # each scaled exactly by its largest component first: no overflow or underflow
        forward = forward / np.abs(forward).max()
        up = np.divide(self.up, np.abs(self.up).max())
        sine = np.linalg.norm(np.cross(forward, up)) / (
            np.linalg.norm(forward) * np.linalg.norm(up))
        if sine < 1e-6:  # the image's horizontal axis is forward × up
            raise _problem(f"{list(self.up)} is parallel to the view direction "
                           "(look_at - position): the image has no horizontal axis", ".up")
        return self

    def camera(self) -> Camera:
        """The Camera."""
        return Camera(self.position, self.look_at, self.up, self.fov, self.width, self.height)


# ------------------------------------------------------------------------- materials

PROJECTIONS = ("uv", "xy", "xz", "yz")


def _choice(options: tuple[str, ...]) -> Any:
    """A field that is one of ``options``."""
    def check(value: Any) -> str:
        if value not in options:
            raise _problem(f"expected one of {', '.join(options)}, found {value!r}")
        return value
    return Annotated[str, PlainValidator(check)]


class _TextureFields(_Section):
    """The keys of a texture (pipeline/scene/model.py ``TextureMap``)."""

    texture: File
    projection: _choice(PROJECTIONS) = "uv"
    scale: Annotated[float, PlainValidator(lambda v: _number(v, 0.0, lo_open=True))] = 1.0
    wrap: _choice(WRAPS) = "repeat"

    def texture_map(self) -> TextureMap:
        return TextureMap(self.texture, self.projection, self.scale, self.wrap)

    def canonical(self) -> dict[str, Any]:
        """All keys, defaults filled, the file as a string."""
        return {k: str(v) if isinstance(v, Path) else v for k, v in self.model_dump().items()}


class _BlendFile(_TextureFields):
    """``materials.NAME.blend``: blended with ``material`` by the texture's value."""

    material: Annotated[str, PlainValidator(_material_name)]


class _BumpFile(_TextureFields):
    """``materials.NAME.bump``: a height map of ``height`` scene units at value 1."""

    height: Annotated[float, PlainValidator(_number)]


class _MaterialFile(_Section):
    """``materials.NAME``; each model's subclass (generated from the model's declared
    parameters) adds its ``model`` tag and a field per parameter. ``blend`` and ``bump``
    (any model) add surface detail."""

    model: str
    blend: _BlendFile | None = None
    bump: _BumpFile | None = None
    parameters: ClassVar[tuple[SceneParam, ...]] = ()

    @classmethod
    def _missing(cls, key: str, value: dict[str, Any]) -> str:
        return f"missing required key '{key}' for model {value['model']}"

    @model_validator(mode="after")
    def _rule(self) -> _MaterialFile:
        rule = MATERIAL_PARAMETERS[self.model].rule
        problem = rule(self.given()) if rule else None
        if problem:
            raise _problem(problem)
        return self

    @model_validator(mode="after")
    def _conserves_energy(self) -> _MaterialFile:
        """kd + ρs · (the model's specular albedo bound at the largest γ the material can
        be edited to) ≤ 1 in every channel (pipeline/math/brdf.py
        ``specular_albedo_bound``; Ward-Dür has no finite bound and is not checked)."""
        if self.model == "lambert":
            return self
        values = self.model_dump()
        gamma = values["gamma_range"][1] if values.get("gamma_range") else values["gamma"]
        bound = specular_albedo_bound(self.model, gamma)
        if bound is None:
            return self
        total = np.add(values["albedo"], np.multiply(values["specular"], bound))
        channel = int(np.argmax(total))
        if total[channel] > 1.0 + 1e-9:
            kd, rho = values["albedo"][channel], values["specular"][channel]
            raise _problem(
                f"albedo + specular x {bound:.3g} = {kd:g} + {rho:g} x {bound:.3g} = "
                f"{total[channel]:.3g} > 1 in the {('red', 'green', 'blue')[channel]} "
                f"channel: the material reflects more light than it receives "
                f"({bound:.3g} is the most a {self.model} lobe of specular 1 reflects, at "
                f"gamma {gamma:g}); lower albedo or specular")
        return self

    def material(self, name: str) -> tuple[Material, dict[str, Any]]:
        """The Material called ``name`` and its canonical dictionary: the keys given and
        the ``filled`` defaults."""
        params = {p.name: _plain(getattr(self, p.name)) for p in self.parameters
                  if p.name in self.model_fields_set or p.filled}
        albedo = params.pop("albedo")
        canonical = {"model": self.model, "albedo": albedo, **params}
        blend = bump = None
        if self.blend is not None:
            blend = Blend(self.blend.material, self.blend.texture_map())
            canonical["blend"] = self.blend.canonical()
        if self.bump is not None:
            bump = Bump(self.bump.texture_map(), self.bump.height)
            canonical["bump"] = self.bump.canonical()
        return Material(name, self.model, tuple(albedo), params, blend, bump), canonical


def _parameter_type(param: SceneParam) -> Any:
    """The field type that validates one declared parameter (None: absent)."""
    if param.kind == "rgb":
        return Annotated[Vector, PlainValidator(lambda v: _vector(v, 3, param.lo, param.hi))]
    if param.kind == "range":
        return Annotated[Vector | None, PlainValidator(lambda v: _range(v, param.lo, param.hi))]

    def number(value: Any, info: ValidationInfo) -> float:
        bounds = info.data.get(param.within) if param.within else None
        if bounds:
            return _number(value, *bounds)
        return _number(value, param.lo, param.hi, param.lo_open)
    return Annotated[float | None, PlainValidator(number)]


def _parameter_default(param: SceneParam) -> Any:
    """The field default: required (``...``), the filled default (three equal values for
    rgb) or None."""
    if param.required:
        return ...
    if not param.filled:
        return None
    return (param.default,) * 3 if param.kind == "rgb" else param.default


def _material_model(model: str, params: tuple[SceneParam, ...]) -> type[_MaterialFile]:
    """The pydantic model of a material of ``model`` with the declared ``params``."""
    cls = create_model(f"Material_{model}", __base__=_MaterialFile,
                       model=(Literal[model], ...),
                       **{p.name: (_parameter_type(p), _parameter_default(p)) for p in params})
    cls.parameters = params
    return cls


MaterialFile = _union(tuple(_material_model(m, spec.params)
                            for m, spec in MATERIAL_PARAMETERS.items()),
                      "model", MATERIAL_MODELS)

# --------------------------------------------------------------------------- objects


class _Plane(_Section):
    """A plane of ``size`` (x, z) centred at the origin, cut into ``segments`` ×
    ``segments`` squares (two triangles each)."""

    type: Literal["plane"]
    size: Annotated[Vector, PlainValidator(lambda v: _vector(v, 2, 0.0))] = (1.0, 1.0)
    segments: Annotated[int, PlainValidator(lambda v: _integer(v, 1))] = 1


class _Sphere(_Section):
    """A sphere of ``radius``, an icosphere of ``subdivisions``."""

    type: Literal["sphere"]
    radius: Annotated[float, PlainValidator(lambda v: _number(v, 0.0, lo_open=True))] = 1.0
    subdivisions: Annotated[int, PlainValidator(lambda v: _integer(v, 0))] = 3


class _Box(_Section):
    """A box of ``size`` (x, y, z) centred at the origin."""

    type: Literal["box"]
    size: Annotated[Vector, PlainValidator(lambda v: _vector(v, 3, 0.0))] = (1.0, 1.0, 1.0)


PrimitiveFile = _union((_Plane, _Sphere, _Box), "type", PRIMITIVES)


def _matrix(value: Any) -> tuple[Vector, ...]:
    """Four rows of four numbers."""
    if not isinstance(value, list) or len(value) != 4:
        raise _problem("expected 4 rows of 4 numbers")
    return tuple(_vector(row, 4, at=f"[{i}]") for i, row in enumerate(value))


def _scale(value: Any) -> Vector:
    """Three non-zero scale factors (or one for all)."""
    s = _vector(value)
    if min(abs(x) for x in s) == 0.0:
        raise _problem("scale must be non-zero")
    return s


class _TransformFile(_Section):
    """An object's transform: a ``matrix``, or ``scale``, then rotations about x, y, z
    (``rotate``, degrees), then ``translate``."""

    matrix: Annotated[tuple[Vector, ...] | None, PlainValidator(_matrix)] = None
    translate: Point = (0.0, 0.0, 0.0)
    rotate: Point = (0.0, 0.0, 0.0)
    scale: Annotated[Vector, PlainValidator(_scale)] = (1.0, 1.0, 1.0)

    @classmethod
    def _combination(cls, value: dict[str, Any]) -> str | None:
        if "matrix" in value and len(value) > 1:
            return "'matrix' cannot be combined with translate/rotate/scale"
        return None

    @model_validator(mode="after")
    def _regular(self) -> _TransformFile:
        if abs(np.linalg.det(np.array(self.rows())[:3, :3])) < 1e-12:
            raise _problem("transform is singular")
        return self

    def rows(self) -> tuple[Vector, ...]:
        """The 4×4 object-to-world matrix, row-major, for column vectors."""
        if self.matrix is not None:
            return tuple(tuple(float(x) for x in row) for row in self.matrix)
        m = np.diag([*self.scale, 1.0])
        for axis, deg in enumerate(self.rotate):
            c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
            rot = np.eye(4)
            i, j = [(1, 2), (2, 0), (0, 1)][axis]
            rot[i, i], rot[i, j], rot[j, i], rot[j, j] = c, -s, s, c
            m = rot @ m
        m[:3, 3] += self.translate
        return tuple(tuple(float(x) for x in row) for row in m)


IDENTITY = tuple(tuple(float(i == j) for j in range(4)) for i in range(4))
MAX_SUBDIVIDE = 4  # objects.NAME.subdivide: at most 256 × an object's faces


class _ObjectFile(_Section):
    """``objects.NAME``: a mesh file or a primitive, a transform and a material;
    ``smooth: true`` welds a mesh file's vertices that share a position (and uv), so
    that a file that splits them by per-face normals (hard edges) is shaded smooth;
    ``subdivide: N`` (0–MAX_SUBDIVIDE) splits every face at its edges' midpoints N times
    (4^N faces each; the surface and its shading normals kept,
    pipeline/scene/meshio.py ``split_edges``): more vertices for the per-vertex light of
    method sg where the light varies faster than the mesh (decision 0048)."""

    material: Annotated[str, PlainValidator(_material_name)]
    mesh: Annotated[Path | None, PlainValidator(_file)] = None
    smooth: bool = False
    subdivide: Annotated[int, PlainValidator(lambda v: _integer(
        v, 0, MAX_SUBDIVIDE, " (each step 4× the faces)"))] = 0
    primitive: Annotated[PrimitiveFile | None, _tagged("type", PRIMITIVES)] = None
    transform: _TransformFile | None = None

    @classmethod
    def _combination(cls, value: dict[str, Any]) -> str | None:
        if ("mesh" in value) == ("primitive" in value):
            return "expected exactly one of 'mesh' or 'primitive'"
        return None

    def scene_object(self, name: str) -> tuple[SceneObject, dict[str, Any]]:
        """The SceneObject called ``name`` and its canonical dictionary."""
        # a plane's default ``segments: 1`` is left out, so that the canonical form (and
        # every key) of scenes written before the option stays as it was
        primitive = None if self.primitive is None else {
            k: _plain(v) for k, v in self.primitive.model_dump().items()
            if not (k == "segments" and v == 1)}
        canonical: dict[str, Any] = ({"mesh": str(self.mesh)} if self.mesh is not None
                                     else {"primitive": primitive})
        rows = IDENTITY if self.transform is None else self.transform.rows()
        canonical["transform"] = _plain(rows)
        canonical["material"] = self.material
        if self.smooth:  # left out when false: keys of scenes without it stay as they were
            canonical["smooth"] = True
        if self.subdivide:  # left out when 0, as smooth
            canonical["subdivide"] = self.subdivide
        return SceneObject(name, self.mesh, primitive, rows, self.material), canonical


# ---------------------------------------------------------------------------- lights
# Fields in alphabetical order: a light's values are checked in that order.


class _LightSection(_Section):
    """``lights[i]``; each type's subclass adds its ``type`` tag and fields."""

    type: str

    def light(self) -> tuple[Light, dict[str, Any]]:
        """The Light and its canonical dictionary: the keys given, files as strings."""
        params = {k: str(v) if isinstance(v, Path) else v for k, v in self.given().items()}
        return Light(self.type, params), {"type": self.type, **params}


class _PointLight(_LightSection):
    type: Literal["point"]
    intensity: Colour
    position: Point


class _SpotLight(_LightSection):
    type: Literal["spot"]
    angle: Annotated[float, PlainValidator(lambda v: _number(v, 0.0, 90.0, lo_open=True))]
    direction: Direction
    falloff: Annotated[float | None, PlainValidator(lambda v: _number(v, 0.0, 1.0))] = None
    intensity: Colour
    position: Point


class _DirectionalLight(_LightSection):
    type: Literal["directional"]
    direction: Direction
    irradiance: Colour


class _QuadLight(_LightSection):
    """A parallelogram ``corner + u·edge_u + v·edge_v`` emitting ``radiance`` towards
    edge_u × edge_v; ``object`` names the emitter's mesh; ``samples`` shadow rays."""

    type: Literal["quad"]
    corner: Point
    edge_u: Point
    edge_v: Point
    object: Annotated[str | None, PlainValidator(_object_name)] = None
    radiance: Colour
    samples: Annotated[int | None, PlainValidator(_square_count)] = None

    @model_validator(mode="after")
    def _has_area(self) -> _QuadLight:
        if math.hypot(*np.cross(self.edge_u, self.edge_v)) == 0.0:
            raise _problem("edge_u and edge_v are parallel or zero (the quad has no area)")
        return self


class _EnvironmentLight(_LightSection):
    """A latitude-longitude map ``file`` turned by ``rotation`` degrees about ``axis``
    (default +y), radiance × ``scale``."""

    type: Literal["environment"]
    axis: Direction | None = None
    file: File
    rotation: Annotated[float | None, PlainValidator(_number)] = None
    scale: Annotated[float | None, PlainValidator(lambda v: _number(v, 0.0))] = None


LightFile = _union((_PointLight, _SpotLight, _DirectionalLight, _QuadLight, _EnvironmentLight),
                   "type", LIGHT_TYPES)


# ----------------------------------------------------------------------------- scene


class _SceneFile(_Section):
    """The whole file."""

    format: Annotated[str, PlainValidator(_format)]
    name: Annotated[str, PlainValidator(_scene_name)]
    camera: _CameraFile
    materials: Annotated[dict[str, MaterialFile], BeforeValidator(_mapping)] = {}
    objects: Annotated[dict[str, _ObjectFile], BeforeValidator(_objects)]
    lights: Annotated[list[LightFile], BeforeValidator(_lights)] = []
    settings: Annotated[dict[str, Any], PlainValidator(_mapping)] = {}
    methods: Annotated[tuple[str, ...] | None, PlainValidator(_methods)] = None


_SCENE = TypeAdapter(_SceneFile)
_MATERIAL = TypeAdapter(MaterialFile)


def _names(doc: Any, section: str) -> list[str]:
    """The names defined in a mapping section of the document (for references to them)."""
    names = doc.get(section) if isinstance(doc, dict) else None
    return [str(k) for k in names] if isinstance(names, dict) else []


def scene_from_document(path: Path, doc: Any) -> Scene:
    """The Scene of the parsed YAML document ``doc`` of the scene file ``path``; the first
    problem as a PrtError naming the file and the key path."""
    spec = _validated(_SCENE, doc, path, {"path": path, "materials": _names(doc, "materials"),
                                          "objects": _names(doc, "objects")})
    materials, raw_materials = {}, {}
    for name, material in spec.materials.items():
        materials[name], raw_materials[name] = material.material(name)
    check_surface_detail(path, materials)
    objects, raw_objects = {}, {}
    for name, obj in spec.objects.items():
        objects[name], raw_objects[name] = obj.scene_object(name)
    lights = [light.light() for light in spec.lights]
    raw: dict[str, Any] = {
        "camera": {k: _plain(v) for k, v in spec.camera.model_dump().items()},
        "materials": raw_materials,
        "objects": raw_objects,
        "lights": [canonical for _, canonical in lights],
        "settings": dict(spec.settings),
        "material_table": list(materials),
    }
    if spec.methods is not None:
        raw["methods"] = list(spec.methods)
    return Scene(path, spec.name, raw, methods=spec.methods)


def check_surface_detail(path: Path, materials: dict[str, Material]) -> None:
    """A blend names another material that has no blend or bump of its own, and every
    texture reads (pipeline/images.py ``read_texture``); a blend's values lie in
    [0, 1]. The first problem as a PrtError naming the scene file (keys) or the texture
    file (its content)."""
    for name, material in materials.items():
        if material.blend is not None:
            other = material.blend.material
            where = f"materials.{name}.blend.material"
            if other == name:
                raise PrtError(path, f"{where}: a material cannot blend with itself")
            if materials[other].blend is not None or materials[other].bump is not None:
                raise PrtError(path, f"{where}: {other!r} has a blend or bump of its own; "
                               "a blend's second material must be plain")
            values = read_texture(material.blend.texture.file)
            outside = (values < 0.0) | (values > 1.0)
            if outside.any():
                y, x = (int(i) for i in np.argwhere(outside)[0])
                raise PrtError(material.blend.texture.file,
                               f"{where[:-len('material')]}texture: blend weight "
                               f"{values[y, x]:g} at texel (x {x}, y {y}) is outside [0, 1]")
        if material.bump is not None:
            read_texture(material.bump.texture.file)


def material_from_spec(path: Path, name: str, spec: dict[str, Any]
                       ) -> tuple[Material, dict[str, Any]]:
    """The material ``name`` of the scene file ``path`` from its (edited) canonical
    dictionary, validated as in the file, and its new canonical dictionary."""
    material = _validated(_MATERIAL, spec, path, {"path": path}, f"materials.{name}")
    return material.material(name)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (above); raise
    PrtError naming the file and key on problems."""
    path = Path(path).resolve()
    if not path.is_file():
        raise PrtError(path, "scene file not found")
    return scene_from_document(path, load_yaml(path))


def default_scene_path() -> Path:
    """The embedded default scene (the Cornell box with a glossy floor)."""
    checkout = Path(__file__).resolve().parents[2] / "scenes" / "cornell_box.yaml"
    if checkout.is_file():
        return checkout
    from importlib.resources import files

    return Path(str(files("pipeline.scenes") / "cornell_box.yaml"))


def check_one_environment(scene: Scene, method: str) -> None:
    """PrtError unless ``scene`` has exactly one environment light whose map reads as a
    valid latitude-longitude map (for the methods lit by a map alone; checked before
    anything is baked: a lighting stage would refuse the map only after the geometry
    stage has run)."""
    count = sum(light.type == "environment" for light in scene.lights)
    if count != 1:
        raise PrtError(scene.path, f"lights: method {method} renders exactly one environment "
                       f"light; the scene has {count}")
    read_environment(scene.environment_file())
