"""Run-time edits of a loaded scene: material γ, ρs and albedo, light moves, the
environment map's file, rotation and scale, the camera's position.

Each returns a new Scene whose document (its canonical dictionary, pipeline/scene/model.py)
holds the edit, and reports a bad edit as a PrtError naming the scene file.
Which of them re-bakes what follows from the stage keys: none for d2i's light moves and
BRDF edits, the lighting grid of method triple for a new map file, nothing for a map
rotation (a lookup shift there) or scale (a factor on the result).
"""

from __future__ import annotations

import math
from pathlib import Path

from pipeline.errors import PrtError
from pipeline.scene.file import material_from_spec
from pipeline.scene.model import Scene

EDITABLE_KEYS = ("gamma", "specular", "albedo")


def with_material_edits(scene: Scene, edits: list[str]) -> Scene:
    """The scene with run-time material edits ``NAME.KEY=VALUE`` applied: NAME a material
    or an object (meaning its material), KEY one of :data:`EDITABLE_KEYS`, VALUE a number
    or ``r,g,b``. Each edited material is validated as in the file; when the material has
    a gamma_range (the range its PCA basis was baked over), γ must lie in it (no
    extrapolation)."""
    materials, raw = scene.materials, dict(scene.document["materials"])
    for edit in edits:
        where = f"--set {edit}"
        target, eq, value_text = edit.partition("=")
        name, dot, key = target.rpartition(".")
        if not eq or not dot:
            raise PrtError(scene.path, f"{where}: expected NAME.KEY=VALUE, e.g. floor.gamma=40")
        if name in scene.objects:
            name = scene.objects[name].material
        if name not in materials:
            raise PrtError(scene.path, f"{where}: no material or object named {name!r}")
        if key not in EDITABLE_KEYS:
            raise PrtError(scene.path, f"{where}: cannot edit {key!r} at run time (editable: "
                           f"{', '.join(EDITABLE_KEYS)})")
        try:
            numbers = [float(v) for v in value_text.split(",")]
        except ValueError:
            raise PrtError(scene.path, f"{where}: expected a number or r,g,b, found "
                           f"{value_text!r}") from None
        spec = dict(raw[name])
        if key != "albedo" and spec["model"] == "lambert":
            raise PrtError(scene.path, f"{where}: material {name!r} is Lambertian; it has "
                           f"no {key}")
        if key == "gamma" and "gamma_range" in spec:
            lo, hi = spec["gamma_range"]
            if len(numbers) != 1 or not lo <= numbers[0] <= hi:
                raise PrtError(scene.path, f"{where}: gamma {value_text} is outside the baked "
                               f"PCA range [{lo:g}, {hi:g}] of material {name!r}; widen its "
                               "gamma_range in the scene file and re-bake")
        spec[key] = numbers[0] if len(numbers) == 1 else numbers
        raw[name] = material_from_spec(scene.path, name, spec)[1]
    return scene.edited("materials", raw)


def with_light_offset(scene: Scene, index: int, offset: tuple[float, float, float]) -> Scene:
    """The scene with light ``index`` moved by ``offset`` (scene units, world frame): a
    point or spot light's position, a quad light's corner. Directional and environment
    lights have no position; moving them, or to a non-finite place, is an error."""
    light = scene.lights[index]
    key = {"point": "position", "spot": "position", "quad": "corner"}.get(light.type)
    if key is None:
        raise PrtError(scene.path, f"lights[{index}]: a {light.type} light has no position "
                       "to move")
    moved = [float(a) + float(b) for a, b in zip(light.params[key], offset, strict=True)]
    if not all(math.isfinite(v) for v in moved):
        raise PrtError(scene.path, f"lights[{index}].{key}: moved to a non-finite position "
                       f"{moved}")
    raw = list(scene.document["lights"])
    raw[index] = {**raw[index], key: moved}
    return scene.edited("lights", raw)


def with_environment_rotation(scene: Scene, degrees: float) -> Scene:
    """The scene with every environment light turned to ``degrees`` about +y (the
    scene file's ``rotation``). A method that bakes the map unrotated (triple) renders
    it without a re-bake."""
    if not math.isfinite(degrees):
        raise PrtError(scene.path, f"environment rotation {degrees!r}: expected a finite "
                       "number of degrees")
    return _with_environment_field(scene, "rotation", degrees, "turn")


def with_environment_scale(scene: Scene, scale: float) -> Scene:
    """The scene with every environment light's radiance × ``scale`` (the scene file's
    ``scale``, replaced; ≥ 0). The methods that bake the map (triple, sg) bake it
    unscaled and multiply at run time: no re-bake."""
    if not math.isfinite(scale) or scale < 0:
        raise PrtError(scene.path, f"environment scale {scale!r}: expected a finite number "
                       ">= 0")
    return _with_environment_field(scene, "scale", scale, "scale")


def _with_environment_field(scene: Scene, name: str, value: float, verb: str) -> Scene:
    """The scene with field ``name`` of every environment light set to ``value``;
    PrtError where it has none to ``verb``."""
    if not any(light.type == "environment" for light in scene.lights):
        raise PrtError(scene.path, f"the scene has no environment light to {verb}")
    raw = [{**r, name: float(value)} if r["type"] == "environment" else r
           for r in scene.document["lights"]]
    return scene.edited("lights", raw)


def with_camera_position(scene: Scene, position: tuple[float, float, float]) -> Scene:
    """The scene seen from ``position`` (scene units), still looking at its look_at."""
    moved = [float(v) for v in position]
    if tuple(moved) == tuple(scene.camera.look_at):
        raise PrtError(scene.path, "camera moved onto its look_at point")
    return scene.edited("camera", {**scene.document["camera"], "position": moved})


def with_environment_file(scene: Scene, path: str | Path) -> Scene:
    """The scene lit by the map ``path`` instead of its environment lights' files (its
    rotation and scale kept). A method that bakes the map (triple, sg) bakes its lighting
    for the new file apart (:attr:`Scene.environment_view`), never over the file's own."""
    if not any(light.type == "environment" for light in scene.lights):
        raise PrtError(scene.path, "the scene has no environment light to give a map")
    file = Path(path).resolve()
    if not file.is_file():
        raise PrtError(file, "environment map not found")
    raw = [{**r, "file": str(file)} if r["type"] == "environment" else r
           for r in scene.document["lights"]]
    return scene.edited("lights", raw, relit_from=scene.relit_from or scene.environment_file())


def _numbers(where: str, text: str, count: int, path) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise PrtError(path, f"{where}: expected {count} finite numbers separated by commas, "
                       f"found {text!r}")
    return values


def with_light_move(scene: Scene, move: str) -> Scene:
    """The scene with ``INDEX=DX,DY,DZ`` applied (``prt render --move-light``): light
    INDEX (an index into ``lights``) moved by that offset (:func:`with_light_offset`)."""
    where = f"--move-light {move}"
    index_text, eq, offset = move.partition("=")
    if not eq or not index_text.strip().isdigit():
        raise PrtError(scene.path, f"{where}: expected INDEX=DX,DY,DZ, e.g. 0=0.1,0,-0.2")
    index = int(index_text)
    if index >= len(scene.lights):
        raise PrtError(scene.path, f"{where}: no light {index} (the scene has "
                       f"{len(scene.lights)})")
    return with_light_offset(scene, index, tuple(_numbers(where, offset, 3, scene.path)))


def with_camera_text(scene: Scene, position: str) -> Scene:
    """The scene seen from ``X,Y,Z`` (``prt render --camera``), still looking at its
    look_at point (:func:`with_camera_position`)."""
    return with_camera_position(scene, tuple(_numbers(f"--camera {position}", position, 3,
                                                      scene.path)))


def with_run_time_edits(scene: Scene, sets: list[str] = (), moves: list[str] = (),
                        camera: str | None = None, env_file: str | Path | None = None,
                        env_rotate: float | None = None,
                        env_scale: float | None = None) -> Scene:
    """Every run-time edit of ``prt render`` applied, in its order: material edits
    (``--set``), light moves (``--move-light``), the camera (``--camera``), the map's file
    (``--env``), turn (``--env-rotate``) and scale (``--env-scale``). ``prt view``
    applies its edits through this one function, so that a frame it saves is the frame
    ``prt render`` renders."""
    scene = with_material_edits(scene, list(sets)) if sets else scene
    for move in moves:
        scene = with_light_move(scene, move)
    if camera is not None:
        scene = with_camera_text(scene, camera)
    if env_file is not None:
        scene = with_environment_file(scene, env_file)
    if env_rotate is not None:
        scene = with_environment_rotation(scene, env_rotate)
    if env_scale is not None:
        scene = with_environment_scale(scene, env_scale)
    return scene
