"""The scene model: an immutable, validated scene — one canonical document and the typed
values read from it (pipeline/scene/file.py reads a scene file into one;
pipeline/scene/edits.py makes edited copies by writing the document).

:meth:`Scene.section` gives the canonical JSON value of a dotted section path, which is
what stage keys hash (with the SHA-256 of every file a section names).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.math.envmap import rotation_about

_FILE_HASHES: dict[tuple[str, int, int], str] = {}


def file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes, cached per (path, size, mtime)."""
    st = path.stat()
    cache_key = (str(path), st.st_size, st.st_mtime_ns)
    if cache_key not in _FILE_HASHES:
        _FILE_HASHES[cache_key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return _FILE_HASHES[cache_key]


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


# The largest image side in pixels (16K): a frame buffer of 16384² RGB float32 pixels is
# 3 GiB, and the G-buffer several times that; a larger size is a typo, not a request.
MAX_IMAGE_SIDE = 16384


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
class TextureMap:
    """A scalar texture on a surface (pipeline/math/textures.py): the image ``file``
    (PNG or EXR), where its coordinates come from (``projection``: ``uv`` the mesh's
    own uv; ``xy``, ``xz``, ``yz`` two world coordinates of the hit point, in that
    order), ``scale`` (uv multiplied by it; for a projection, texture repeats per scene
    unit) and ``wrap`` (``repeat`` or ``clamp``)."""

    file: Path
    projection: str = "uv"
    scale: float = 1.0
    wrap: str = "repeat"


@dataclass(frozen=True)
class Blend:
    """A spatially varying BRDF: the material's own BRDF blended with ``material``'s,
    the texture's value t ∈ [0, 1] the weight of ``material`` (f = (1 − t) f_a + t f_b)."""

    material: str
    texture: TextureMap


@dataclass(frozen=True)
class Bump:
    """A bump map: the surface displaced along its normal by ``height`` × the texture's
    value (scene units), for shading only (pipeline/math/textures.py)."""

    texture: TextureMap
    height: float


@dataclass(frozen=True)
class Material:
    """One named material: ``model`` a key of
    :data:`pipeline.math.brdf.MATERIAL_PARAMETERS`, diffuse RGB ``albedo`` and the model's
    other parameters as validated (the BRDF module interprets them); optionally a
    ``blend`` with a second material and a ``bump`` map (run-time surface detail,
    pipeline/render/surface_detail.py)."""

    name: str
    model: str
    albedo: tuple[float, float, float]
    params: dict[str, Any] = field(default_factory=dict)
    blend: Blend | None = None
    bump: Bump | None = None


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
class Environment:
    """An environment light as renderers read it: its latitude-longitude map ``file``,
    its ``rotation`` in degrees about the unit ``axis`` (right-handed; the scene file's
    ``rotation`` and ``axis``, default +y; the run-time edit ``--env-rotate`` sets the
    degrees) and its radiance ``scale``."""

    file: Path
    rotation: float = 0.0
    scale: float = 1.0
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)

    @property
    def to_world(self) -> np.ndarray:
        """The 3×3 map-to-world rotation (pipeline/math/envmap.py)."""
        return rotation_about(self.axis, self.rotation)

    @property
    def turn_about_y(self) -> float | None:
        """The rotation as degrees about +y where the axis is ±y (a shift of the map's
        longitude: renderers take it without trigonometry per pixel), else None."""
        x, y, z = self.axis
        if x != 0.0 or z != 0.0:
            return None
        return self.rotation if y > 0 else -self.rotation


@dataclass(frozen=True)
class Light:
    """One light; ``params`` holds the type's fields as validated (see
    :mod:`pipeline.scene.file`)."""

    type: str
    params: dict[str, Any]

    def environment(self) -> Environment:
        """This environment light's map, rotation and scale (defaults: 0°, 1)."""
        assert self.type == "environment", self.type
        p = self.params
        axis = [float(x) for x in p.get("axis", (0.0, 1.0, 0.0))]
        length = math.hypot(*axis)
        return Environment(Path(p["file"]), float(p.get("rotation", 0.0)),
                           float(p.get("scale", 1.0)), (axis[0] / length, axis[1] / length,
                                                       axis[2] / length))


@dataclass(frozen=True)
class Scene:
    """A validated scene: ``document``, its canonical, path-resolved dictionary — the one
    thing a run-time edit writes (pipeline/scene/edits.py), what :meth:`section` reads
    and stage keys hash — and the typed values read from it (:attr:`camera`,
    :attr:`materials`, :attr:`objects`, :attr:`lights`, :attr:`settings`, each read once).
    ``methods``: the rendering methods the scene is baked for, as the file names them
    (None when it does not)."""

    path: Path
    name: str
    document: dict[str, Any]
    methods: tuple[str, ...] | None = None
    resized_from: tuple[int, int] | None = None
    relit_from: Path | None = None  # the file's own map, when --env lit it by another

    @cached_property
    def camera(self) -> Camera:
        c = self.document["camera"]
        return Camera(tuple(c["position"]), tuple(c["look_at"]), tuple(c["up"]), c["fov"],
                      c["width"], c["height"])

    @cached_property
    def materials(self) -> dict[str, Material]:
        return {name: _material(name, spec)
                for name, spec in self.document["materials"].items()}

    @cached_property
    def objects(self) -> dict[str, SceneObject]:
        return {name: _scene_object(name, spec)
                for name, spec in self.document["objects"].items()}

    @cached_property
    def lights(self) -> tuple[Light, ...]:
        return tuple(Light(spec["type"], {k: v for k, v in spec.items() if k != "type"})
                     for spec in self.document["lights"])

    @property
    def settings(self) -> dict[str, Any]:
        return self.document["settings"]

    def edited(self, section: str, value: Any, **changes: Any) -> Scene:
        """This scene with the top-level document section ``section`` (``camera``,
        ``materials``, ``lights``, ...) replaced by ``value``, already canonical and
        validated, and dataclass fields ``changes``; every typed value is read anew."""
        return replace(self, document={**self.document, section: value}, **changes)

    def with_image_size(self, width: int, height: int) -> Scene:
        """The same scene rendered at ``width`` × ``height`` pixels."""
        if width < 1 or height < 1:
            raise PrtError(self.path, f"image size {width}x{height}: width and height must "
                           "be positive")
        if max(width, height) > MAX_IMAGE_SIDE:
            raise PrtError(self.path, f"image size {width}x{height}: at most "
                           f"{MAX_IMAGE_SIDE} pixels per side")
        original = self.resized_from or (self.camera.width, self.camera.height)
        return self.edited("camera", {**self.document["camera"], "width": width,
                                      "height": height},
                           resized_from=None if (width, height) == original else original)

    @property
    def view(self) -> str | None:
        """``"WxH"`` when the image size differs from the scene file's (a run-time
        ``--size``), else None. The camera-dependent artifacts of such a view are kept
        apart from the file's own (:class:`pipeline.engine.store.Workdir`), so that a preview
        at another size never replaces the file's bake."""
        if self.resized_from is None:
            return None
        return f"{self.camera.width}x{self.camera.height}"

    @property
    def environment_view(self) -> str | None:
        """``"env-<stem>-<digest>"`` (the new map's file name and 8 hex digits of its
        path) when the scene is lit at run time by another map than its file's
        (``--env``), else None: the environment-dependent artifacts of such a view are
        kept apart as :attr:`view`'s are."""
        file = self.environment_file()
        if self.relit_from is None or file is None or file == self.relit_from:
            return None
        digest = hashlib.sha256(str(file).encode()).hexdigest()[:8]
        stem = re.sub(r"[^A-Za-z0-9_.-]", "_", file.stem)[:40]
        return f"env-{stem}-{digest}"

    def with_settings(self, overrides: dict[str, Any]) -> Scene:
        """The same scene with stage-parameter ``overrides`` added to its settings."""
        return self.edited("settings", {**self.settings, **overrides})

    @property
    def environment(self) -> Environment | None:
        """The scene's first environment light, None without one (the methods lit by a
        map alone render exactly one)."""
        return next((light.environment() for light in self.lights
                     if light.type == "environment"), None)

    def environment_file(self) -> Path | None:
        """The map file of the scene's first environment light, None without one."""
        return None if self.environment is None else self.environment.file

    def section(self, dotted: str) -> Any:
        """The canonical value at a dotted path (``camera``, ``objects.floor.material``,
        ``materials.white``). File paths (``mesh``, ``file``) are replaced by the SHA-256
        of the file's content: editing the file changes the value, moving the scene and
        its files elsewhere does not (so are a material's ``texture`` files). Missing
        paths give ``None``. ``environment.file`` is
        the SHA-256 of the scene's environment map (its first environment light's
        ``file``; None without one): the map's content without its rotation and scale."""
        if dotted == ENVIRONMENT_FILE:
            path = self.environment_file()
            return None if path is None else {"sha256": file_hash(path)}
        node: Any = self.document
        parts = dotted.split(".")
        for part in parts:
            if not isinstance(node, dict) or part not in node:
                return None
            node = node[part]
        if parts[-1] in FILE_KEYS and isinstance(node, str):
            return {"sha256": file_hash(Path(node))}
        return _with_file_hashes(node)


def _texture(spec: dict[str, Any]) -> TextureMap:
    return TextureMap(Path(spec["texture"]), spec["projection"], spec["scale"], spec["wrap"])


def _material(name: str, spec: dict[str, Any]) -> Material:
    """The Material of a canonical material dictionary (pipeline/scene/file.py)."""
    params = {k: v for k, v in spec.items() if k not in ("model", "albedo", "blend", "bump")}
    blend = spec.get("blend")
    bump = spec.get("bump")
    return Material(name, spec["model"], tuple(spec["albedo"]), params,
                    None if blend is None else Blend(blend["material"], _texture(blend)),
                    None if bump is None else Bump(_texture(bump), bump["height"]))


def _scene_object(name: str, spec: dict[str, Any]) -> SceneObject:
    """The SceneObject of a canonical object dictionary (pipeline/scene/file.py)."""
    return SceneObject(name, Path(spec["mesh"]) if "mesh" in spec else None,
                       spec.get("primitive"), tuple(tuple(row) for row in spec["transform"]),
                       spec["material"])


ENVIRONMENT_FILE = "environment.file"  # the scene section of the environment map's bytes
FILE_KEYS = ("mesh", "file", "texture")  # keys whose (path) values section() hashes


def _with_file_hashes(node: Any) -> Any:
    """``node`` with each path under a key of :data:`FILE_KEYS` in it replaced by its
    file's SHA-256."""
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            if key in FILE_KEYS and isinstance(value, str):
                out[key] = {"sha256": file_hash(Path(value))}
            else:
                out[key] = _with_file_hashes(value)
        return out
    if isinstance(node, list):
        return [_with_file_hashes(v) for v in node]
    return node
