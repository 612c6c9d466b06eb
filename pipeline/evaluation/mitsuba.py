"""Cross-check renders with Mitsuba 3 (optional: the ``mitsuba`` extra).

:func:`render` draws one of our scenes with Mitsuba at the settings of our Monte-Carlo
reference: exactly our merged geometry (world-space vertices, faces and the vertex normals
whose barycentric blend is our shading normal), Lambertian materials as two-sided
``diffuse`` BSDFs (our shading normal is turned to face the viewer, so our surfaces
reflect on both sides), every other BRDF model as the Python BSDF ``prt_brdf``
(pipeline/evaluation/mitsuba_bsdfs.py: the formulas written anew, two-sided like our
shading, with our tangent frame: each mesh carries its faces' dP/du from our uv as the
face attribute ``face_dpdu``), the scene camera (vertical fov, row 0 at the top, image
right = forward × up) and our lights in our units. Spot lights (their falloff differs)
raise :class:`PrtError`.

Quad lights become Mitsuba ``area`` emitters, which emit on the side of the triangles'
counter-clockwise face normal; we emit towards edge_u × edge_v. When the quad names an
``object`` whose mesh is the quad itself (planar, inside the rectangle, same area, vertex
normals along edge_u × edge_v: the Cornell box luminaire) the emitter sits on that mesh,
wound to face edge_u × edge_v, and the mesh keeps its own material, as in Mitsuba's
``cbox-rgb.xml``; no second coincident surface exists. (Mitsuba draws its own light
samples; the quad's ``samples`` count does not apply.) Otherwise the light is a separate
two-triangle rectangle, black (reflectance 0) and opaque: it is seen emitting on its front
and casts shadows, where ours is no surface at all and shows emission on the named object
only, so pixels that see it, or light passing through it, differ. (A ``null`` BSDF would
let paths through but still block Mitsuba's shadow rays.)

Environment maps (our convention is Mitsuba's; measured with ``emitter.eval`` and renders,
Mitsuba 3.9.1). A unit world direction d (the way a ray escapes) is rotated into the map,
d' = Rᵀ d with R the light's ``rotation`` in degrees about its ``axis`` (right-handed,
default +y, i.e. Mitsuba's to_world = rotate(axis, θ)), and looked up at::

    u = atan2(d'.x, −d'.z) / 2π  (mod 1)        v = acos(d'.y) / π
    column x = W·u − ½  (periodic)              row y = (H − 1)·v  (row 0 at the top)

with bilinear interpolation between the four texels around (x, y): column c is centred at
u = (c + ½)/W, row r at v = r/(H − 1), so row 0 is the +y pole and row H − 1 the −y pole.
The image centre (u = ½) lies along +z, u = ¼ along +x; ``scale`` multiplies radiance.
"""

from __future__ import annotations

import functools
import glob
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.errors import PrtError
from pipeline.evaluation import mitsuba_bsdfs
from pipeline.math.frames import face_tangents
from pipeline.scene.model import Scene

TRANSPORTS = ("full", "direct", "env-direct")
# Where Debian/Ubuntu put LLVM 19 (package libllvm19), which Dr.Jit's LLVM backend loads.
_LIBLLVM_GLOBS = ("/usr/lib/*-linux-gnu/libLLVM-19.so", "/usr/lib/*-linux-gnu/libLLVM.so.19*",
                  "/usr/lib/llvm-19/lib/libLLVM.so")
_COINCIDENT_TOL = 1e-4  # relative to the quad's longer edge (distances) or area


@dataclass(frozen=True)
class MitsubaRender:
    """One Mitsuba frame: ``rgb`` (height, width, 3) float32 linear RGB, row 0 at the top;
    ``render_s`` the seconds of ``mi.render`` plus the sync into NumPy (includes JIT
    compilation in LLVM variants); ``load_s`` the seconds to build and load the scene."""

    rgb: np.ndarray
    render_s: float
    load_s: float
    variant: str
    spp: int


@functools.cache
def variant() -> str:
    """``llvm_ad_rgb`` when Dr.Jit's LLVM backend loads, else ``scalar_rgb``. Points
    ``DRJIT_LIBLLVM_PATH`` at LLVM 19 (if unset and found) before importing mitsuba."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        found = [p for pattern in _LIBLLVM_GLOBS for p in sorted(glob.glob(pattern))
                 if os.path.isfile(p)]
        if found:
            os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise PrtError(None, "Mitsuba 3 is not installed; install the 'mitsuba' extra "
                       "(pip install 'prt-pipeline[mitsuba]') to cross-check with "
                       f"Mitsuba ({exc})") from None
    if "llvm_ad_rgb" in mi.variants() and dr.has_backend(dr.JitBackend.LLVM):
        return "llvm_ad_rgb"
    return "scalar_rgb"


def _mitsuba() -> Any:
    """The mitsuba module with :func:`variant` active."""
    chosen = variant()
    import mitsuba as mi

    mi.set_variant(chosen)
    mitsuba_bsdfs.register(mi)
    return mi


def _rgb(value: Any) -> dict[str, Any]:
    return {"type": "rgb", "value": [float(x) for x in value]}


def _mesh(mi: Any, name: str, vertices: np.ndarray, faces: np.ndarray,
          normals: np.ndarray | None, bsdf: Any, emitter: Any | None,
          dpdu: np.ndarray | None = None) -> Any:
    """A Mitsuba triangle mesh (world frame) with vertex normals if given, and the faces'
    dP/du (F, 3) as the face attribute read by the ``prt_brdf`` BSDFs, if given."""
    props = mi.Properties()
    props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    mesh = mi.Mesh(name, len(vertices), len(faces), props=props,
                   has_vertex_normals=normals is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(vertices, np.float32).ravel()
    params["faces"] = np.ascontiguousarray(faces, np.uint32).ravel()
    if normals is not None:
        params["vertex_normals"] = np.ascontiguousarray(normals, np.float32).ravel()
    params.update()
    if dpdu is not None:
        mesh.add_attribute(mitsuba_bsdfs.TANGENT_ATTRIBUTE, 3,
                           np.ascontiguousarray(dpdu, np.float32).ravel())
    return mesh


def _object_meshes(geometry: Mapping[str, Any]) -> dict[str, tuple[np.ndarray, ...]]:
    """Each object's (vertices, normals, faces) with faces indexing its own vertices, and
    its faces' dP/du (our tangents before they are made orthogonal to the shading normal:
    pipeline/device/raytrace.py), zero where the uv mapping is degenerate."""
    vertices = np.asarray(geometry["vertices"], np.float32)
    normals = np.asarray(geometry["normals"], np.float32)
    faces = np.asarray(geometry["faces"], np.int64)
    face_object = np.asarray(geometry["face_object"])
    dpdu = face_tangents(np.asarray(geometry["vertices"], np.float64),
                         np.asarray(geometry["uv"], np.float64), faces)
    out = {}
    for index, name in enumerate(geometry["object_names"]):
        mine = face_object == index
        own = faces[mine]
        if len(own):
            used, local = np.unique(own, return_inverse=True)
            out[name] = (vertices[used], normals[used], local.reshape(-1, 3), dpdu[mine])
    return out


def _coincides(vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray,
               corner: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray) -> bool:
    """Whether a mesh is the quad corner + s·edge_u + t·edge_v (s, t ∈ [0, 1]): every
    vertex in its plane and rectangle, the same area, vertex normals along edge_u × edge_v."""
    n = np.cross(edge_u, edge_v)
    area = float(np.linalg.norm(n))
    n /= area
    tol = _COINCIDENT_TOL * max(np.linalg.norm(edge_u), np.linalg.norm(edge_v))
    rel = vertices.astype(np.float64) - corner
    st = np.linalg.lstsq(np.stack([edge_u, edge_v], 1), rel.T, rcond=None)[0]
    p = vertices[faces].astype(np.float64)
    mesh_area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return bool(np.all(np.abs(rel @ n) <= tol)
                and np.all((st >= -_COINCIDENT_TOL) & (st <= 1 + _COINCIDENT_TOL))
                and abs(mesh_area.sum() - area) <= _COINCIDENT_TOL * area
                and np.all(normals @ n >= 1.0 - _COINCIDENT_TOL))


def _facing(vertices: np.ndarray, faces: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``faces`` rewound so every counter-clockwise face normal has n·normal ≥ 0."""
    p = vertices[faces].astype(np.float64)
    back = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) @ n < 0
    out = faces.copy()
    out[back] = faces[back][:, ::-1]
    return out


def _integrator(scene: Scene, transport: str, max_depth: int) -> dict[str, Any]:
    if transport == "full":
        return {"type": "path", "max_depth": max_depth, "hide_emitters": False}
    if transport in ("direct", "env-direct"):
        return {"type": "direct", "hide_emitters": False}
    raise PrtError(scene.path, f"transport {transport!r} has no Mitsuba equivalent "
                   f"(expected one of: {', '.join(TRANSPORTS)})")


def _sensor(mi: Any, scene: Scene, geometry: Mapping[str, Any], spp: int, seed: int,
            pixel_filter: str) -> dict[str, Any]:
    """Perspective camera; clip planes enclose the whole scene (scene units)."""
    cam = scene.camera
    vertices = np.asarray(geometry["vertices"], np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    reach = float(np.linalg.norm(np.subtract(cam.position, (lo + hi) / 2))
                  + np.linalg.norm(hi - lo))
    return {
        "type": "perspective",
        "fov": cam.fov,
        "fov_axis": "y",
        "near_clip": 1e-4 * reach,
        "far_clip": 2.0 * reach,
        "to_world": mi.ScalarTransform4f().look_at(origin=list(cam.position),
                                                   target=list(cam.look_at), up=list(cam.up)),
        "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                 "pixel_format": "rgb", "component_format": "float32",
                 "rfilter": {"type": pixel_filter}},
        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
    }


def bsdf_dict(scene: Scene, material_name: str) -> dict[str, Any]:
    """The Mitsuba BSDF of one of the scene's materials: Lambert as a two-sided
    ``diffuse``, every other model (``pipeline.math.brdf.MATERIAL_PARAMETERS``) as a
    ``prt_brdf`` of that model with the material's parameters (F0 from ``ior`` if given)."""
    material = scene.materials[material_name]
    if material.blend is not None or material.bump is not None:
        raise PrtError(scene.path, f"material {material_name!r}: blends and bump maps have "
                       "no Mitsuba equivalent here")
    if material.model not in mitsuba_bsdfs.MODELS:
        raise PrtError(scene.path, f"material {material_name!r} ({material.model}) has no "
                       "Mitsuba equivalent")
    return bsdf_dict_from(material.model, material.albedo, material.params)


def bsdf_dict_from(model: str, albedo: Any, params: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`bsdf_dict` of a material ``model`` with diffuse ``albedo`` and the scene
    material's other ``params`` (``specular`` required for glossy models)."""
    if model == "lambert":
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": _rgb(albedo)}}
    f0 = params.get("f0", mitsuba_bsdfs.DEFAULT_F0)
    if "ior" in params:
        f0 = ((params["ior"] - 1.0) / (params["ior"] + 1.0)) ** 2
    specular = np.broadcast_to(np.asarray(params["specular"], np.float64), 3)
    out: dict[str, Any] = {"type": mitsuba_bsdfs.PLUGIN, "model": model,
                           "gamma": float(params["gamma"]),
                           "alpha_ratio": float(params.get("alpha_ratio", 1.0)),
                           "cxy": float(params.get("cxy", -1.0)),
                           "cz": float(params.get("cz", 1.0)), "f0": float(f0)}
    for c, kd, ks in zip("rgb", albedo, specular, strict=True):
        out[f"kd_{c}"], out[f"ks_{c}"] = float(kd), float(ks)
    return out


def scene_dict(scene: Scene, geometry: Mapping[str, Any], transport: str, spp: int,
               seed: int = 0, max_depth: int = -1, pixel_filter: str = "box") -> dict[str, Any]:
    """A ``mi.load_dict`` scene: our geometry (world frame, scene units) as one mesh per
    object, its material (:func:`bsdf_dict`), camera and lights. ``geometry`` holds the
    geometry artifact's ``vertices``, ``normals``, ``uv``, ``faces``, ``face_object`` and
    ``object_names``.
    ``transport``: ``full`` (path tracing, ``max_depth`` −1 = unbounded with Russian
    roulette), ``direct`` (emitter and BSDF sampling with MIS) or ``env-direct`` (direct
    lighting from the environment only; quad meshes stay as plain surfaces)."""
    mi = _mitsuba()
    integrator = _integrator(scene, transport, max_depth)
    lights = [light for light in scene.lights
              if transport != "env-direct" or light.type == "environment"]
    if transport == "env-direct" and not lights:
        raise PrtError(scene.path, "transport env-direct needs an environment light")
    if sum(light.type == "environment" for light in lights) > 1:
        raise PrtError(scene.path, "Mitsuba takes one environment light per scene")

    meshes = _object_meshes(geometry)
    bsdfs = {}
    for name, obj in scene.objects.items():
        bsdfs[name] = mi.load_dict(bsdf_dict(scene, obj.material))

    out: dict[str, Any] = {"type": "scene", "integrator": integrator,
                           "sensor": _sensor(mi, scene, geometry, spp, seed, pixel_filter)}
    emitters: dict[str, tuple[Any, np.ndarray]] = {}  # object -> (emitter, its normal)
    for i, light in enumerate(lights):
        p = light.params
        if light.type == "point":
            out[f"light_{i}"] = {"type": "point", "position": p["position"],
                                 "intensity": _rgb(p["intensity"])}
        elif light.type == "directional":
            out[f"light_{i}"] = {"type": "directional", "direction": p["direction"],
                                 "irradiance": _rgb(p["irradiance"])}
        elif light.type == "environment":
            env = light.environment()
            out[f"light_{i}"] = {
                "type": "envmap", "filename": str(env.file), "scale": env.scale,
                "to_world": mi.ScalarTransform4f().rotate(list(env.axis), env.rotation)}
        elif light.type == "quad":
            corner, edge_u, edge_v = (np.asarray(p[k], np.float64)
                                      for k in ("corner", "edge_u", "edge_v"))
            emitter = mi.load_dict({"type": "area", "radiance": _rgb(p["radiance"])})
            host = p.get("object")
            if host in meshes and host not in emitters and _coincides(
                    *meshes[host][:3], corner, edge_u, edge_v):
                emitters[host] = (emitter, np.cross(edge_u, edge_v))
            else:
                rect = np.stack([corner, corner + edge_u, corner + edge_u + edge_v,
                                 corner + edge_v])
                out[f"light_{i}"] = _mesh(mi, f"light_{i}", rect,
                                          np.array([[0, 1, 2], [0, 2, 3]]), None,
                                          mi.load_dict({"type": "diffuse",
                                                        "reflectance": _rgb([0, 0, 0])}),
                                          emitter)
        else:
            raise PrtError(scene.path, f"lights[{i}]: {light.type} lights have no Mitsuba "
                           "equivalent (their falloff differs)")

    for name, (vertices, normals, faces, dpdu) in meshes.items():
        emitter, n = emitters.get(name, (None, None))
        if emitter is not None:
            faces = _facing(vertices, faces, n)
        out[f"object_{name}"] = _mesh(mi, name, vertices, faces, normals, bsdfs[name], emitter,
                                      dpdu)
    return out


def render(scene: Scene, geometry: Mapping[str, Any], transport: str, spp: int,
           seed: int = 0, max_depth: int = -1) -> MitsubaRender:
    """Render ``scene`` with Mitsuba (arguments as :func:`scene_dict`; ``seed`` seeds the
    ``independent`` sampler, so equal seeds give equal images)."""
    mi = _mitsuba()
    t0 = time.perf_counter()
    loaded = mi.load_dict(scene_dict(scene, geometry, transport, spp, seed, max_depth))
    t1 = time.perf_counter()
    rgb = np.array(mi.render(loaded), dtype=np.float32)  # the sampler holds the seed
    t2 = time.perf_counter()
    return MitsubaRender(rgb, t2 - t1, t1 - t0, variant(), spp)


# One material of each model for the cross-check (studies/mitsuba_crosscheck.py,
# tests/test_mitsuba.py), on a diffuse albedo of half the material's own (kd_scale) so that
# the glossy lobe shows: ρs small enough for the scene's energy check (decision 0013) on
# kd ≤ 0.45. Lafortune's Cxy ≠ −Cz and Cook-Torrance's and Ashikhmin-Shirley's F0 ≠ 0.04
# exercise those terms; anisotropic Ward's ratio 3 makes the tangent matter.
CROSSCHECK_PARAMETERS: dict[str, dict[str, Any]] = {
    "lambert": {},
    "blinn_phong": {"specular": 0.15, "gamma": 20.0},
    "ward": {"specular": 0.5, "gamma": 0.15},
    "ward_duer": {"specular": 0.4, "gamma": 0.15},
    "ward_anisotropic": {"specular": 0.5, "gamma": 0.08, "alpha_ratio": 3.0},
    "lafortune": {"specular": 0.5, "gamma": 30.0, "cxy": -0.9, "cz": 1.0},
    "cook_torrance": {"specular": 0.13, "gamma": 0.2, "f0": 0.3},
    "ashikhmin_shirley": {"specular": 0.5, "gamma": 100.0, "f0": 0.5},
}


def with_model(scene: Scene, materials: tuple[str, ...], model: str,
               kd_scale: float = 0.5) -> Scene:
    """``scene`` with each material of ``materials`` turned into ``model``: its albedo ×
    ``kd_scale`` and :data:`CROSSCHECK_PARAMETERS`' other parameters, validated as in a
    scene file."""
    from pipeline.scene.file import material_from_spec

    raw = dict(scene.document["materials"])
    for name in materials:
        spec = {"model": model,
                "albedo": [kd_scale * a for a in scene.materials[name].albedo],
                **CROSSCHECK_PARAMETERS[model]}
        raw[name] = material_from_spec(scene.path, name, spec)[1]
    return scene.edited("materials", raw)
