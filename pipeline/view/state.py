"""The viewer's state: the edits a page sends, checked against the method's declared
run-time edits (``Method.edits``) and turned into the arguments of ``prt render``
(``--set``, ``--move-light``, ``--camera``, ``--env-rotate``, ``--env-scale``,
``--option``), which are
then applied by the function ``prt render`` applies them with
(pipeline/scene/edits.py ``with_run_time_edits``). The viewer never edits a scene any
other way: a frame it shows or saves is the frame of the command it prints.

A page's edits (JSON)::

    {"lights": {"0": [dx, dy, dz]},          # scene units, world frame
     "environment": 90.0,                    # the map's rotation in degrees
     "environment_scale": 2.0,               # the map's radiance scale
     "camera": [azimuth, elevation],         # degrees about the look_at point, from the file's
     "materials": {"floor": {"gamma": 40, "specular": 0.3, "albedo": [r, g, b]}},
     "options": {"budget": 320}}

Absent keys (and zero moves) are the scene file's values.
"""

from __future__ import annotations

import json
import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.method import Method
from pipeline.scene.edits import with_run_time_edits
from pipeline.scene.model import Scene

MOVABLE = {"point": "position", "spot": "position", "quad": "corner"}
MATERIAL_KEYS = ("gamma", "specular", "albedo")
ELEVATION_LIMIT = 85.0  # degrees: the camera never reaches its up direction
LIGHT_REACH = 0.5  # a light moves at most this × the scene's diagonal along each axis
SCALE_MOST = 1e6  # the environment's scale in the viewer: within [0, this]


def number(value: Any, where: str) -> float:
    """``value`` as a finite float, or PrtError naming ``where``."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PrtError(where, f"expected a number, found {value!r}") from None
    if not math.isfinite(x):
        raise PrtError(where, f"expected a finite number, found {value!r}")
    return x


def text(x: float) -> str:
    """A float as text that reads back to the same float (``prt render``'s arguments)."""
    return repr(float(x))


@dataclass(frozen=True)
class Resolved:
    """A page's edits resolved: the edited scene, the method's options (parsed as
    ``--option`` parses them), the ``prt render`` arguments that give the same scene and
    options, and a key of exactly those (the render cache's)."""

    scene: Scene
    options: dict[str, Any]
    args: tuple[str, ...]
    key: str
    groups: frozenset[str]  # the edit groups that differ from the scene file


class ViewScene:
    """A scene as ``prt view`` shows it with one method: the file's scene (resized),
    what the page needs to build its controls (:meth:`spec`), and the resolution of a
    page's edits (:meth:`resolve`)."""

    def __init__(self, scene: Scene, method: Method, scene_arg: str | None, size: str | None,
                 diagonal: float, workdir_arg: str | None = None) -> None:
        self.scene, self.method = scene, method
        self.scene_arg, self.size, self.workdir_arg = scene_arg, size, workdir_arg
        self.diagonal = diagonal
        cam = scene.camera
        offset = np.subtract(cam.position, cam.look_at)
        self.radius = float(np.linalg.norm(offset))
        self.azimuth0 = math.degrees(math.atan2(offset[0], offset[2]))
        self.elevation0 = math.degrees(math.asin(max(-1.0, min(1.0, offset[1] /
                                                               self.radius))))

    # what the page builds its controls from --------------------------------------
    def spec(self) -> dict[str, Any]:
        m, sc, edits = self.method, self.scene, set(self.method.edits)
        cam = sc.camera
        forward = np.subtract(cam.look_at, cam.position)
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, cam.up)
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        lights = [{"index": i, "type": light.type, "key": MOVABLE[light.type],
                   "position": [float(v) for v in light.params[MOVABLE[light.type]]]}
                  for i, light in enumerate(sc.lights) if light.type in MOVABLE] \
            if "light" in edits else []
        materials = []
        for name, mat in sc.materials.items():
            keys = [k for k in MATERIAL_KEYS if k in edits and
                    (k == "albedo" or mat.model != "lambert")]
            if not keys:
                continue
            p = {**mat.params, **sc.document["materials"][name]}  # albedo: the file's
            row: dict[str, Any] = {"name": name, "model": mat.model, "keys": keys}
            if "gamma" in keys:
                row["gamma"] = float(p["gamma"])
                row["gamma_range"] = [float(v) for v in self.gamma_range(name)]
            if "specular" in keys:
                row["specular"] = _rgb_or_float(p.get("specular", 0.0))
            if "albedo" in keys:
                row["albedo"] = _rgb(p.get("albedo", 0.0))
            materials.append(row)
        env = sc.environment
        # the ``environment`` edit: the map's turn and its scale (a factor on the frame
        # for every method that turns the map at run time; its stages never read it)
        environment = None if env is None or "environment" not in edits else \
            {"rotation": env.rotation, "scale": env.scale}
        return {
            "scene": sc.name, "method": m.name, "description": m.description,
            "width": cam.width, "height": cam.height, "edits": [e for e in m.edits],
            "lights": lights, "materials": materials,
            "environment": environment,
            "camera": {"orbit": "camera" in edits, "elevation": self.elevation0,
                       "limit": ELEVATION_LIMIT, "right": right.tolist(),
                       "up": up.tolist()},
            "diagonal": self.diagonal, "reach": LIGHT_REACH * self.diagonal,
            "options": [{"name": o.name, "type": o.type.__name__, "default": o.default,
                         "help": o.help, "least": o.least, "choices": list(o.choices)}
                        for o in m.options],
            "drag_options": dict(m.drag_options), "edit_modes": dict(m.edit_modes),
            "command": self.command(()),
        }

    def gamma_range(self, name: str) -> tuple[float, float]:
        """Material ``name``'s baked γ range (else [γ/4, 4γ], as a γ sequence sweeps)."""
        p = self.scene.materials[name].params
        return tuple(p.get("gamma_range") or (p["gamma"] / 4, p["gamma"] * 4))

    # a page's edits -> prt render's arguments -> the scene ---------------------------
    def resolve(self, edits: dict[str, Any], extra_options: dict[str, Any] | None = None
                ) -> Resolved:
        """The scene, options and ``prt render`` arguments of a page's ``edits``
        (``extra_options``: options that override the page's, a drag's); PrtError for
        an edit the method does not follow at run time or one out of its range."""
        if not isinstance(edits, dict):
            raise PrtError("edits", "expected an object of edits")
        allowed = set(self.method.edits)
        unknown = set(edits) - {"lights", "environment", "environment_scale", "camera",
                                "materials", "options"}
        if unknown:
            raise PrtError("edits", f"unknown edit {sorted(unknown)[0]!r}")
        sets: list[str] = []
        moves: list[str] = []
        camera = env_rotate = env_scale = None
        groups: set[str] = set()
        for name, values in sorted((edits.get("materials") or {}).items()):
            if name not in self.scene.materials:
                raise PrtError("materials", f"no material named {name!r}")
            for key in MATERIAL_KEYS:
                if key not in values:
                    continue
                if key not in allowed:
                    raise PrtError(f"{name}.{key}", f"method {self.method.name} does not "
                                   f"edit {key} at run time")
                sets.append(f"{name}.{key}={self._material_value(name, key, values[key])}")
                groups.add(key)
        for index, offset in sorted((edits.get("lights") or {}).items(),
                                    key=lambda kv: int(kv[0])):
            if "light" not in allowed:
                raise PrtError("lights", f"method {self.method.name} does not move lights "
                               "at run time")
            d = [number(v, f"lights[{index}]") for v in offset]
            if len(d) != 3:
                raise PrtError(f"lights[{index}]", "expected an offset dx, dy, dz")
            reach = LIGHT_REACH * self.diagonal
            if max(abs(v) for v in d) > reach * (1 + 1e-9):
                raise PrtError(f"lights[{index}]", f"a light moves at most {reach:.4g} "
                               "scene units along each axis in the viewer")
            if any(d):
                moves.append(f"{int(index)}={','.join(text(v) for v in d)}")
                groups.add("light")
        if edits.get("camera") is not None:
            if "camera" not in allowed:
                raise PrtError("camera", f"method {self.method.name} bakes for its camera "
                               "(no orbit at run time)")
            az, el = (number(v, "camera") for v in edits["camera"])
            if az or el:
                camera = ",".join(text(v) for v in self.orbit(az, el))
                groups.add("camera")
        if edits.get("environment") is not None:
            if "environment" not in allowed:
                raise PrtError("environment", f"method {self.method.name} does not turn "
                               "the environment at run time")
            deg = number(edits["environment"], "environment")
            env = self.scene.environment
            if env is not None and deg != env.rotation:
                env_rotate = text(deg)
                groups.add("environment")
        if edits.get("environment_scale") is not None:
            if "environment" not in allowed:
                raise PrtError("environment_scale", f"method {self.method.name} does not "
                               "scale the environment at run time")
            scale = number(edits["environment_scale"], "environment_scale")
            if not 0 <= scale <= SCALE_MOST:
                raise PrtError("environment_scale", f"{scale!r} is outside [0, {SCALE_MOST:g}]")
            env = self.scene.environment
            if env is not None and scale != env.scale:
                env_scale = text(scale)
                groups.add("environment")
        given = {k: str(v) for k, v in sorted((edits.get("options") or {}).items())}
        given |= {k: str(v) for k, v in (extra_options or {}).items()}
        options = self.method.option_values(given)
        defaults = self.method.option_values({})
        option_args = [f"{k}={v}" for k, v in options.items() if v != defaults[k]]
        scene = with_run_time_edits(self.scene, sets, moves, camera, None,
                                    None if env_rotate is None else float(env_rotate),
                                    None if env_scale is None else float(env_scale))
        args = [*(a for s in sets for a in ("--set", s)),
                *(a for mv in moves for a in ("--move-light", mv)),
                *(("--camera", camera) if camera else ()),
                *(("--env-rotate", env_rotate) if env_rotate else ()),
                *(("--env-scale", env_scale) if env_scale else ()),
                *(a for o in option_args for a in ("--option", o))]
        return Resolved(scene, options, tuple(args), json.dumps(args), frozenset(groups))

    def _material_value(self, name: str, key: str, value: Any) -> str:
        where = f"{name}.{key}"
        if key == "albedo" or isinstance(value, list | tuple):
            values = [number(v, where) for v in (value if isinstance(value, list | tuple)
                                                 else [value])]
            if any(v < 0 or v > 1 for v in values):
                raise PrtError(where, f"{value!r} is outside [0, 1]")
            return ",".join(text(v) for v in values)
        x = number(value, where)
        if key == "gamma":
            lo, hi = self.gamma_range(name)
            if not lo <= x <= hi:
                raise PrtError(where, f"gamma {x:g} is outside the baked range [{lo:g}, "
                               f"{hi:g}] of material {name!r}")
        elif not 0 <= x <= 1:
            raise PrtError(where, f"{x:g} is outside [0, 1]")
        return text(x)

    def orbit(self, azimuth: float, elevation: float) -> tuple[float, float, float]:
        """The camera position turned ``azimuth`` degrees about +y and raised
        ``elevation`` degrees (within ±:data:`ELEVATION_LIMIT`) about its look_at point,
        at the file's distance."""
        el = self.elevation0 + elevation
        if abs(el) > ELEVATION_LIMIT + 1e-9:
            raise PrtError("camera", f"elevation {el:.4g}° is beyond ±{ELEVATION_LIMIT:g}°")
        az, el = math.radians(self.azimuth0 + azimuth), math.radians(el)
        look = self.scene.camera.look_at
        r = self.radius
        return (look[0] + r * math.cos(el) * math.sin(az), look[1] + r * math.sin(el),
                look[2] + r * math.cos(el) * math.cos(az))

    def command(self, args: tuple[str, ...], out: str = "view.exr",
                exposure: float = 0.0) -> str:
        """The ``prt render`` command that renders the frame of ``args``."""
        argv = ["prt", "render", *([self.scene_arg] if self.scene_arg else []), "--method",
                self.method.name]
        if self.size:
            argv += ["--size", self.size]
        if self.workdir_arg:
            argv += ["--workdir", self.workdir_arg]
        argv += [*args, *(("--exposure", text(exposure)) if exposure else ()), "--out", out]
        return shlex.join(argv)


def _rgb(value: Any) -> list[float]:
    v = np.broadcast_to(np.asarray(value, float), (3,))
    return [float(x) for x in v]


def _rgb_or_float(value: Any) -> float:
    """A scalar control for ρs (its mean where the file gives r, g, b)."""
    return float(np.mean(value))


def scene_diagonal(workdir_geometry: Path | None, scene: Scene) -> float:
    """The diagonal of the scene's bounding box (from the baked geometry's attributes),
    else the camera's distance to its look_at point."""
    from pipeline.engine.store import open_artifact

    if workdir_geometry is not None:
        try:
            attrs = open_artifact(workdir_geometry, "geometry").attrs
            return float(np.linalg.norm(np.subtract(attrs["bbox_max"], attrs["bbox_min"])))
        except (PrtError, KeyError, OSError):
            pass
    return float(np.linalg.norm(np.subtract(scene.camera.position, scene.camera.look_at)))
