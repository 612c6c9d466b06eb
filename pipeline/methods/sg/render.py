"""Method ``sg`` (paper 003 §5): per pixel, the spherical Gaussians of the hit face's 3
vertices at the 3 views around the direction to the eye, blended and integrated against
the prefiltered environment, plus the diffuse SH term (kernels/sg/sg_render.cl; NumPy twins
:func:`view_triangles` and :func:`shade_numpy`).

Artifacts (the contract between issue 17's stages and this renderer): ``geometry`` (vertices,
faces: global vertex indices), ``sg.relax`` (``sg_lobes``, sg.fit's lobes relabelled
against flips over every mesh edge: per vertex, view of
``sg_transport.view_directions()`` and lobe slot, (w_rgb, μ_xyz, λ), world frame, w in
1/sr, λ = 1/σ² in rad⁻²; ``count`` lobes per vertex), ``sg.diffuse`` (``sg_diffuse``:
per vertex the diffuse transfer (3 channels × 25 SH coefficients), albedo/π and cosine
included) and ``sg.env_prefilter`` (the map convolved by normalised SGs, pipeline/math/
sg.py).

**The pixel.** A camera ray hits face (v₀, v₁, v₂) at barycentrics f_a (Embree's u, v:
f = (1 − u − v, u, v)); ω_o = −ray direction (world, unit, towards the eye).

* *View triangle.* The 92 views are the vertices of 180 geodesic triangles (their convex
  hull, :class:`ViewTriangulation`); the triangle (a, b, c) whose cone holds ω_o gives
  weights β = M⁻¹ω_o, M = [a b c] (columns), normalised to sum 1: the gnomonic
  barycentrics (the point where the ray ω_o meets the flat triangle), ≥ 0 inside, 1 at
  a view, continuous across edges (on an edge both triangles solve the same 2 × 2
  system). Found in two levels: the icosahedron face (20 cones, their edges are great
  circles through the sub-triangles' edges) and then its 9 sub-triangles.
* *Lobes.* Per slot s (slot s is the same lobe at every view and vertex: the fit keeps
  correspondences), with W_ab = f_a β_b over the 3 vertices × 3 views:
  w = Σ W w_ab, μ = normalise(Σ W μ_ab), and λ = exp(Σ W log λ_ab) (linear in log σ,
  the stack's own coordinate; ``lambda_blend="linear"``: Σ W λ_ab). A highlight moves
  with μ between views instead of cross-fading (tests/test_sg_render.py).
* *Integral.* ∫ w G(ω; μ, λ) L(ω) dω = w · sg.integral(λ) · P(Rᵀμ, σ = 1/√λ), P the
  stack looked up at the map-space mean (R the environment's rotation about its axis,
  ``Environment.to_world``), times the light's ``scale``.
* *Diffuse.* Σ_a f_a max(0, Σ_k transfer[v_a, c, k] L_k,c) · scale (negative SH ringing
  clamped per vertex), L = sh.project_latlong of the map turned by the light's rotation
  (projected once, turned per frame by ``sh.rotate_y`` about +y, ``sh.rotate`` about
  any other axis): the vertices' diffuse radiance D computed per frame on the host
  (V × 3n² products) and interpolated in the kernel, instead of 3n² per pixel.
* Pixels that miss see the environment map (bilinear, rotated, scaled).

Camera rays, their hits and the view triangles are kept per camera (a G-buffer), so an
environment-rotation frame runs the shading kernel only.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cache
from typing import Any

import numpy as np

from pipeline.device import cl
from pipeline.device.raytrace import RayTracer
from pipeline.engine.store import Artifact
from pipeline.errors import PrtError
from pipeline.images import read_environment
from pipeline.math import sg, sh
from pipeline.math.brdf import BrdfParams, pack_materials, scene_brdfs
from pipeline.math.geodesic import icosahedron
from pipeline.methods.sg import source_rings, visibility
from pipeline.methods.sg.brdf_lobe import TABLE, brdf_lobe, lobe_table
from pipeline.methods.sg.sources import FIELDS as SOURCE_FIELDS
from pipeline.methods.sg.sources import split_sources
from pipeline.methods.sg.sources import to_world as sources_to_world
from pipeline.methods.sg.stages.env_prefilter import read_stack
from pipeline.methods.sg.stages.fit import pack_slots, slot_counts
from pipeline.methods.sg.transport import view_directions
from pipeline.render import (
    WORK_GROUP,
    DeviceImage,
    Frame,
    back_face_notes,
    camera_key,
    sees_back,
)
from pipeline.render.rays import aligned_image_rays
from pipeline.scene.model import Scene

SLOTS, FIELDS = 3, 7  # lobe slots per (vertex, view); (w_rgb, μ_xyz, λ) per lobe
LAMBDA_BLENDS = ("log", "linear")
# where the glossy light takes its normal from: the lobes as fitted at the vertex (paper
# 003, the default); the lobes turned towards the pixel's blended normal (decision 0039:
# no gain on bunny_sg and dragon_sg, 8x the shading kernel's time; a gain on coarse
# unoccluded meshes); or the BRDF at the pixel's normal, the vertices' lobes keeping
# visibility and indirect light as a ratio to unshadowed radiances (decision 0042); or
# the BRDF at the pixel's normal against each vertex's visibility map, no lobes
# (decision 0046, pipeline/methods/sg/visibility.py)
NORMALS = ("vertex", "pixel", "ratio", "visibility")
# what a frame shows: everything, or the reflected light of the lobes or of the SH term
COMPONENTS = ("all", "glossy", "diffuse")


# ------------------------------------------------------------------ view triangles


@dataclass(frozen=True)
class ViewTriangulation:
    """The 92 views' geodesic triangles. ``views`` (92, 3) unit, world; ``faces``
    (180, 3) view indices; ``face_inverse`` (180, 3, 3) M⁻¹ of M = [a b c] (columns);
    ``parent_inverse`` (20, 3, 3) the same for the icosahedron's faces and
    ``children`` (20, 9) the triangles inside each."""

    views: np.ndarray
    faces: np.ndarray
    face_inverse: np.ndarray
    parent_inverse: np.ndarray
    children: np.ndarray


@cache
def view_triangulation() -> ViewTriangulation:
    """The triangulation of ``sg_transport.view_directions()`` (their convex hull),
    grouped by the icosahedron face holding each triangle's centroid."""
    from scipy.spatial import ConvexHull

    views = view_directions()
    faces = np.asarray(ConvexHull(views).simplices, np.int64)
    face_inverse = np.linalg.inv(np.transpose(views[faces], (0, 2, 1)))
    corners, ico_faces = icosahedron()
    parent_inverse = np.linalg.inv(np.transpose(corners[ico_faces], (0, 2, 1)))
    centroid = views[faces].mean(axis=1)
    inside = np.einsum("pij,fj->fpi", parent_inverse, centroid).min(axis=2)  # (180, 20)
    parent = inside.argmax(axis=1)
    children = np.stack([np.flatnonzero(parent == p) for p in range(len(ico_faces))])
    return ViewTriangulation(views, faces, face_inverse, parent_inverse, children)


def view_triangles(tri: ViewTriangulation, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The views (P, 3) int32 and weights (P, 3) float64 (≥ 0, sum 1) of the triangle
    holding each unit direction ``wo`` (P, 3): the kernel ``sg_view_lookup``'s twin
    (module docstring)."""
    d = np.asarray(wo, np.float64)
    parent = np.einsum("pij,nj->npi", tri.parent_inverse, d).min(axis=2).argmax(axis=1)
    candidates = tri.children[parent]  # (P, 9)
    beta = np.einsum("ncij,nj->nci", tri.face_inverse[candidates], d)  # (P, 9, 3)
    face = candidates[np.arange(len(d)), beta.min(axis=2).argmax(axis=1)]
    weights = np.maximum(np.einsum("nij,nj->ni", tri.face_inverse[face], d), 0.0)
    weights /= weights.sum(axis=1, keepdims=True)
    return tri.faces[face].astype(np.int32), weights


def _launch(kernel: Any, size: int, args: list[Any], outs: list[np.ndarray]) -> float:
    """One launch over ``size`` work-items (groups of WORK_GROUP) writing ``outs`` (host
    arrays, filled); the kernel's milliseconds."""
    import pyopencl as pcl

    buffers = [pcl.Buffer(cl.context(), pcl.mem_flags.WRITE_ONLY, max(o.nbytes, 4))
               for o in outs]
    event = kernel(cl.queue(), (-(-size // WORK_GROUP) * WORK_GROUP,), (WORK_GROUP,),
                   *args, *buffers)
    ms = cl.event_ms(event)
    for host, buffer in zip(outs, buffers, strict=True):
        if host.size:
            pcl.enqueue_copy(cl.queue(), host, buffer).wait()
    return ms


@cache
def _triangulation_buffers() -> tuple[Any, ...]:
    tri = view_triangulation()
    return tuple(cl.read_only_buffer(a) for a in (
        tri.parent_inverse.astype(np.float32), tri.children.astype(np.int32),
        tri.face_inverse.astype(np.float32), tri.faces.astype(np.int32)))


def device_view_triangles(wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`view_triangles` by the kernel: views (P, 3) int32, weights (P, 3)
    float32, and the kernel's milliseconds."""
    wo = np.ascontiguousarray(wo, np.float32)
    views, weights = np.empty((len(wo), 3), np.int32), np.empty((len(wo), 3), np.float32)
    ms = _launch(cl.kernel("sg_render.cl", "sg_view_lookup"), len(wo),
                 [*_triangulation_buffers(), cl.read_only_buffer(wo), np.int32(len(wo))],
                 [views, weights])
    return views, weights, ms


# -------------------------------------------------------------------------- tables


@dataclass
class SgTables:
    """What a frame reads. ``lobes`` (R, views, 7) float32: the stored slots, vertex by
    vertex (w_rgb 1/sr, μ unit world, λ rad⁻² > 0; data_schema/sg/sg_lobes.yaml v2);
    ``first`` (V + 1,) int32: vertex v's slots are rows first[v] … first[v + 1] − 1;
    ``count`` (V,) lobes per vertex; ``transfer`` (V, 3, 25) float32 (diffuse SH
    transfer); ``stack``/``levels`` the prefiltered map (sg.PrefilterLevels, levels
    (H_ℓ, W_ℓ, 3) float32, W/(m² sr)); ``normals`` (V, 3) float32 the unit vertex
    normals the lobes were fitted at (geometry's), None: the lobes are not turned to the
    pixel's normal (``normal="vertex"``); ``lobe_table`` (M, brdf_lobe.TABLE, 3) float32
    the glossy materials' BRDF lobes (brdf_lobe.lobe_table) and ``vertex_lobe`` (V,)
    int32 each vertex's material row (−1: none), None: no ratio (decision 0042),
    ``lobe_specular`` (M, 3) float32 their ρs and ``node_table`` (M, TABLE, 7) float32
    their node weights (visibility.node_table; None: not made); ``visibility`` (V, texels) uint8 the
    vertices' packed octahedral pyramids of ``visibility_resolution``² texels and
    ``occluder`` (V, 3, n²) float32 their occluder transfer (sg.visibility; None: not
    loaded, decision 0046); ``residual_stack`` the prefiltered map less its bright
    ``sources`` (K, 7) float32 (pipeline/methods/sg/sources.py; None: the map whole, no
    sources) and ``glossy_brdfs`` the M glossy materials in ``lobe_table``'s order;
    ``direct_transfer`` (V, 3, n²) float32 the unbounced part of ``transfer``,
    ``vertex_albedo`` (V, 3) the vertices' kd and ``source_sh`` (n², 3) the SH of the
    map's part its sources hold (map frame): the sources' direct diffuse light is then
    taken from what the vertices see of them (:func:`source_diffuse`; decision 0048);
    ``source_table`` (V, Σ N_s) uint8 and ``source_offsets`` (K + 1,) what each vertex
    sees of each source per turn of the map about +y (sg.source_visibility; None: read
    from the visibility maps; decision 0049)."""

    lobes: np.ndarray
    first: np.ndarray
    count: np.ndarray
    transfer: np.ndarray
    stack: list[np.ndarray]
    levels: sg.PrefilterLevels
    normals: np.ndarray | None = None
    lobe_table: np.ndarray | None = None
    vertex_lobe: np.ndarray | None = None
    lobe_specular: np.ndarray | None = None
    node_table: np.ndarray | None = None
    visibility: np.ndarray | None = None
    visibility_resolution: int = 0
    occluder: np.ndarray | None = None
    residual_stack: list[np.ndarray] | None = None
    sources: np.ndarray | None = None
    glossy_brdfs: list[BrdfParams] | None = None
    direct_transfer: np.ndarray | None = None
    vertex_albedo: np.ndarray | None = None
    source_sh: np.ndarray | None = None
    source_table: np.ndarray | None = None
    source_offsets: np.ndarray | None = None

    @classmethod
    def from_dense(cls, lobes: np.ndarray, count: np.ndarray, transfer: np.ndarray,
                   stack: list[np.ndarray], levels: sg.PrefilterLevels,
                   slots: np.ndarray | None = None, normals: np.ndarray | None = None
                   ) -> SgTables:
        """Tables from lobes in every slot (V, views, 3, 7), storing ``slots`` (V,) slots
        per vertex (default max(count, 1)), and the vertex ``normals`` (V, 3) if given."""
        count = np.asarray(count, np.uint8)
        slots = np.maximum(count, 1) if slots is None else np.asarray(slots)
        rows, first = pack_slots(np.asarray(lobes, np.float32), slots)
        return cls(rows, np.append(first, len(rows)).astype(np.int32), count,
                   np.asarray(transfer, np.float32), stack, levels,
                   None if normals is None else np.ascontiguousarray(normals, np.float32))

    @property
    def nbytes(self) -> int:
        return self.lobes.nbytes + self.first.nbytes + self.count.nbytes \
            + self.transfer.nbytes + sum(level.nbytes for level in self.stack) \
            + sum(0 if a is None else a.nbytes
                  for a in (self.normals, self.lobe_table, self.vertex_lobe,
                            self.lobe_specular, self.node_table, self.visibility,
                            self.occluder, self.source_table))


def load_tables(artifacts: Mapping[str, Artifact], vertex_count: int) -> SgTables:
    """The tables from the artifacts of ``sg.relax`` (no lobes where not given),
    ``sg.diffuse`` and ``sg.env_prefilter`` (and the vertex normals of ``geometry``
    where given),
    checked against each other and the geometry's ``vertex_count`` (one-line
    PrtErrors naming the artifact)."""
    diffuse = artifacts["sg.diffuse"]
    views = view_directions()
    if "sg.relax" in artifacts:
        fit = artifacts["sg.relax"]
        views = fit.read("views")
        if views.shape != view_directions().shape or \
                not np.allclose(views, view_directions(), atol=1e-9):
            raise PrtError("sg.relax", "views: not sg_transport.view_directions() in order; "
                           "re-bake sg.fit")
        lobes = np.ascontiguousarray(fit.read("lobes"), np.float32)
        first = np.asarray(fit.read("first"), np.int64)
        count = np.ascontiguousarray(fit.read("count"), np.uint8)
    else:  # normal=visibility reads no lobes (decision 0046)
        lobes = np.zeros((0, len(views), FIELDS), np.float32)
        first = np.zeros(vertex_count, np.int64)
        count = np.zeros(vertex_count, np.uint8)
    transfer = np.ascontiguousarray(diffuse.read("transfer"), np.float32)
    order = int(diffuse.attrs.get("order", sh.ORDER))
    expected = {"sg.relax lobes": (lobes.shape[1:], (len(views), FIELDS)),
                "sg.relax first": (first.shape, (vertex_count,)),
                "sg.relax count": (count.shape, (vertex_count,)),
                "sg.diffuse transfer": (transfer.shape, (vertex_count, 3, order ** 2))}
    for what, (shape, want) in expected.items():
        if tuple(shape) != want:
            raise PrtError(what.split()[0], f"{what.split()[1]}: shape {tuple(shape)}, "
                           f"expected {want} (geometry has {vertex_count} vertices)")
    slots = slot_counts(first, len(lobes))
    if len(first) and (first[0] != 0 or np.any(slots < 0) or np.any(slots < count)
                       or np.any(slots > SLOTS)):
        raise PrtError("sg.relax", "first: slot rows out of order or fewer than a "
                       "vertex's count")
    if not (np.all(np.isfinite(lobes)) and np.all(lobes[..., 6] > 0)):
        raise PrtError("sg.relax", "lobes: non-finite values or a sharpness λ ≤ 0")
    prefiltered = artifacts["sg.env_prefilter"]
    stack, levels = read_stack(prefiltered)
    residual, _ = read_stack(prefiltered, "residual")
    sources = np.asarray(prefiltered.read("sources"), np.float32).reshape(-1, SOURCE_FIELDS)
    normals = None
    if "geometry" in artifacts:
        normals = np.ascontiguousarray(artifacts["geometry"].read("normals"), np.float32)
        if normals.shape != (vertex_count, 3):
            raise PrtError("geometry", f"normals: shape {normals.shape}, expected "
                           f"{(vertex_count, 3)}")
    direct = np.ascontiguousarray(diffuse.read("direct"), np.float32) \
        if "direct" in diffuse.names else None
    if direct is not None and direct.shape != transfer.shape:
        raise PrtError("sg.diffuse", f"direct: shape {direct.shape}, expected {transfer.shape}")
    return SgTables(lobes, np.append(first, len(lobes)).astype(np.int32), count, transfer,
                    stack, levels, normals, residual_stack=residual, sources=sources,
                    direct_transfer=direct)


def vertex_lobe_tables(brdfs: list[BrdfParams | None], vertex_material: np.ndarray,
                       nodes: bool = False) -> dict[str, Any]:
    """``lobe_table`` (M, TABLE, 3) float32 of the glossy materials among ``brdfs`` (None:
    no glossy part), ``lobe_specular`` (M, 3) their ρs and ``vertex_lobe`` (V,) int32,
    each vertex's row in it (−1: none), from ``vertex_material`` (V,) indices into
    ``brdfs`` (decision 0042); with ``nodes`` also ``node_table`` (M, TABLE, 7)
    (decision 0046) and ``glossy_brdfs`` (decision 0048)."""
    rows, glossy_brdfs = np.full(len(brdfs), -1, np.int32), []
    for m, brdf in enumerate(brdfs):
        if brdf is not None:
            rows[m] = len(glossy_brdfs)
            glossy_brdfs.append(brdf)
    out = {"lobe_table": np.asarray([lobe_table(b) for b in glossy_brdfs],
                                    np.float32).reshape(-1, TABLE, 3),
           "vertex_lobe": rows[np.asarray(vertex_material, np.int64)],
           "lobe_specular": np.asarray([b.specular for b in glossy_brdfs],
                                       np.float32).reshape(-1, 3)}
    if nodes:
        out["node_table"] = np.asarray([visibility.node_table(b) for b in glossy_brdfs],
                                       np.float32).reshape(-1, TABLE, visibility.NODES)
        out["glossy_brdfs"] = glossy_brdfs
    return out


def load_visibility(artifact: Artifact, vertex_count: int, order: int
                    ) -> dict[str, np.ndarray | int]:
    """``visibility``, ``visibility_resolution`` and ``occluder`` of :class:`SgTables` from
    an sg.visibility artifact, checked against the geometry's ``vertex_count`` and
    sg.diffuse's SH ``order``."""
    resolution = int(artifact.attrs["resolution"])
    maps = np.ascontiguousarray(artifact.read("maps"), np.uint8)
    occluder = np.ascontiguousarray(artifact.read("occluder"), np.float32)
    expected = {"maps": (maps.shape, (vertex_count, visibility.level_offsets(resolution)[-1])),
                "occluder": (occluder.shape, (vertex_count, 3, order ** 2))}
    for what, (shape, want) in expected.items():
        if tuple(shape) != want:
            raise PrtError("sg.visibility", f"{what}: shape {tuple(shape)}, expected {want}")
    return {"visibility": maps, "visibility_resolution": resolution, "occluder": occluder}


def load_source_visibility(artifact: Artifact, vertex_count: int, sources: int
                           ) -> dict[str, np.ndarray]:
    """``source_table`` and ``source_offsets`` of :class:`SgTables` from an
    sg.source_visibility artifact, checked against the geometry's ``vertex_count`` and
    the number of ``sources`` sg.env_prefilter holds."""
    table = np.asarray(artifact.read("table"), np.uint8)
    offsets = np.asarray(artifact.read("offsets"), np.int64)
    if len(offsets) != sources + 1 or table.shape != (vertex_count, int(offsets[-1])) \
            or np.any(np.diff(offsets) <= 0):
        raise PrtError("sg.source_visibility", f"table {table.shape}, offsets "
                       f"{offsets.tolist()}: expected {vertex_count} rows and {sources} "
                       "sources' columns (re-bake sg.source_visibility)")
    return {"source_table": table, "source_offsets": offsets}


def scene_lobe_tables(scene: Scene, geometry: Artifact, nodes: bool = False
                      ) -> dict[str, Any]:
    """:func:`vertex_lobe_tables` of the scene's materials on ``geometry``'s vertices
    (its ``material_names``, ``object_ranges``, ``object_material``)."""
    names = list(geometry.attrs["material_names"])
    brdfs: list[BrdfParams | None] = []
    for brdf in scene_brdfs(scene, names):
        glossy_part = brdf.model != "lambert" and max(brdf.specular) > 0
        brdfs.append(replace(brdf, albedo=(0.0, 0.0, 0.0)) if glossy_part else None)
    material = np.full(len(geometry.read("vertices")), len(brdfs), np.int64)
    for (start, end, *_), m in zip(np.asarray(geometry.read("object_ranges")),
                                   np.asarray(geometry.read("object_material")),
                                   strict=True):
        material[start:end] = m
    out = vertex_lobe_tables([*brdfs, None], material, nodes)
    if nodes:  # the vertices' kd, for the sources' direct diffuse light (decision 0048)
        albedo = np.array([*(b.albedo for b in scene_brdfs(scene, names)), (0.0, 0.0, 0.0)])
        out["vertex_albedo"] = albedo[material]
    return out


# ------------------------------------------------------------------------- shading


def turn_rotations(normals: np.ndarray, corner: np.ndarray, bary: np.ndarray,
                   wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel and corner the turn towards the pixel's normal: the unit axis t
    (P, 3, 3) and angle (P, 3) of the rotation taking the corner's mirror direction
    r_a = reflect(ωo, n_a) (returned, (P, 3, 3)) to the pixel's r_p = reflect(ωo, n_p),
    n_p the normalised blend Σ f_a n_a; angle 0 where |r_a × r_p| ≤ 1e-6 or n_p = 0
    (kernels/sg/sg_render.cl, decision 0039; :func:`turn_means` applies it)."""
    n = np.asarray(normals, np.float64)[corner]                              # (P, 3, 3)
    wo = np.asarray(wo, np.float64)
    npix = np.einsum("pa,pac->pc", np.asarray(bary, np.float64), n)
    length = np.linalg.norm(npix, axis=1)
    npix = npix / np.where(length > 0, length, 1.0)[:, None]
    rp = 2.0 * np.sum(wo * npix, axis=1)[:, None] * npix - wo                # (P, 3)
    ra = 2.0 * np.einsum("pc,pac->pa", wo, n)[..., None] * n - wo[:, None]   # (P, 3, 3)
    t = np.cross(ra, rp[:, None])
    sine = np.linalg.norm(t, axis=2)
    ok = (sine > 1e-6) & (length > 0)[:, None]
    t = t / np.where(ok, sine, 1.0)[..., None] * ok[..., None]
    angle = np.where(ok, np.arctan2(sine, np.einsum("pac,pc->pa", ra, rp)), 0.0)
    return t, angle, ra


def turn_means(mean: np.ndarray, lam: np.ndarray, axis: np.ndarray, angle: np.ndarray,
               mirror: np.ndarray) -> np.ndarray:
    """Lobe means (P, 3, B, 3) (pixel, corner, view, xyz) of sharpness ``lam`` (P, 3, B)
    turned about each corner's ``axis`` (P, 3, 3) by G(r_a; μ, λ) × ``angle`` (P, 3),
    r_a the corner's ``mirror`` direction (:func:`turn_rotations`): the lobes about the
    mirror direction follow the pixel's normal, the others stay (decision 0039)."""
    d = mirror[:, :, None] - mean
    theta = np.exp(-0.5 * lam * np.sum(d * d, axis=-1)) * angle[:, :, None]  # (P, 3, B)
    t = np.broadcast_to(axis[:, :, None], mean.shape)
    c, s = np.cos(theta)[..., None], np.sin(theta)[..., None]
    return c * mean + s * np.cross(t, mean) + (1 - c) * np.sum(t * mean, axis=-1,
                                                               keepdims=True) * t


def shade_numpy(tables: SgTables, corner: np.ndarray, bary: np.ndarray, view: np.ndarray,
                view_weight: np.ndarray, light_sh: np.ndarray,
                to_world: np.ndarray | None = None, scale: float = 1.0,
                lambda_blend: str = "log", wo: np.ndarray | None = None,
                ratio: bool = False, visible: bool = False,
                about_y: float | None = None) -> np.ndarray:
    """Radiance (P, 3) of P pixels (the kernel ``sg_shade``'s twin, float64): the face's
    vertices ``corner`` (P, 3) and barycentrics ``bary`` (P, 3), the view triangle's
    ``view`` (P, 3) and weights ``view_weight`` (P, 3), the lighting's SH ``light_sh``
    (25, 3), the environment turned by ``to_world`` (its 3×3 map-to-world rotation,
    any axis; None: unturned), times ``scale``. A slot
    beyond a corner's stored ones is its slot 0 with w = 0; a corner with none adds
    nothing. With the directions to the eye ``wo`` (P, 3) and ``tables.normals``, each
    corner's means are turned towards the pixel's normal (:func:`turn_means`, the
    kernel's PIXEL_NORMAL = 1); without, they are not (PIXEL_NORMAL = 0). ``ratio``
    (with ``wo``, ``tables.normals`` and its lobe tables): the lobes are not turned but
    blended per corner, and the BRDF is applied at the pixel's normal
    (:func:`ratio_glossy`, the kernel's BRDF_RATIO = 1). ``visible`` (with ``wo``,
    ``tables.normals``, its lobe tables and visibility): no lobes, the BRDF at the
    pixel's normal against the corners' visibility (:func:`visibility_glossy`, the kernel
    ``sg_shade_visibility``; ``about_y``: ``to_world``'s turn in degrees where it turns
    the map about +y, as the sources' visibility is read, :func:`source_seen`)."""
    corner = np.asarray(corner, np.int64)
    if visible:
        turn = np.eye(3) if to_world is None else np.asarray(to_world, np.float64)
        seen = source_seen(tables, turn, about_y)
        diffuse = vertex_diffuse(tables.transfer.astype(np.float64), light_sh,
                                 source_diffuse(tables, turn, about_y, seen))[corner]
        return scale * (visibility_glossy(tables, corner, bary, wo, turn, light_sh, seen)
                        + np.einsum("pa,pac->pc", bary.astype(np.float64), diffuse))
    if ratio:
        turn = np.eye(3) if to_world is None else np.asarray(to_world, np.float64)
        diffuse = vertex_diffuse(tables.transfer.astype(np.float64), light_sh)[corner]
        return scale * (ratio_glossy(tables, corner, bary, view, view_weight, wo, turn,
                                     lambda_blend)
                        + np.einsum("pa,pac->pc", bary.astype(np.float64), diffuse))
    turning = wo is not None and tables.normals is not None
    if turning:
        axis, angle, mirror = turn_rotations(tables.normals, corner, bary, wo)
    view = np.asarray(view, np.int64)
    base = tables.first[corner].astype(np.int64)
    stored = tables.first[corner + 1] - base                                  # (P, 3)
    weight = bary[:, :, None].astype(np.float64) * view_weight[:, None, :]  # (P, 3, 3)
    weight = weight * (stored > 0)[:, :, None]
    slots = tables.count[corner].max(axis=1)
    stack = [np.asarray(level, np.float64) for level in tables.stack]
    turn = np.eye(3) if to_world is None else np.asarray(to_world, np.float64)
    out = np.zeros((len(corner), 3))
    for s in range(SLOTS):
        row = np.where(stored > 0, base + np.where(stored > s, s, 0), 0)
        lobe = tables.lobes[row[:, :, None], view[:, None, :]].astype(np.float64)
        keep = (stored > s)[:, :, None]
        w = np.einsum("pab,pabc->pc", weight * keep, lobe[..., 0:3])
        means = lobe[..., 3:6]                                               # (P, 3, 3, 3)
        if turning:
            means = turn_means(means, lobe[..., 6], axis, angle, mirror)
        mu = np.einsum("pab,pabc->pc", weight, means)
        if lambda_blend == "log":
            lam = np.exp(np.einsum("pab,pab->p", weight, np.log(lobe[..., 6])))
        else:
            lam = np.einsum("pab,pab->p", weight, lobe[..., 6])
        length = np.linalg.norm(mu, axis=1)
        ok = (slots > s) & (length > 0)
        mu_map = (mu[ok] / length[ok, None]) @ turn  # Rᵀμ, as rows
        out[ok] += sg.env_integral(stack, tables.levels, mu_map, lam[ok], w[ok])
    diffuse = vertex_diffuse(tables.transfer.astype(np.float64), light_sh)[corner]
    out += np.einsum("pa,pac->pc", bary.astype(np.float64), diffuse)
    return scale * out


def ratio_glossy(tables: SgTables, corner: np.ndarray, bary: np.ndarray, view: np.ndarray,
                 view_weight: np.ndarray, wo: np.ndarray, turn: np.ndarray,
                 lambda_blend: str = "log") -> np.ndarray:
    """The glossy radiance (P, 3) of decision 0042 (the kernel's BRDF_RATIO = 1, float64):
    per channel F + v (U_p − U), v = min(1, F/U), F = Σ_a f_a F_a with F_a corner a's
    lobes blended over its 3 views and integrated, U = Σ_a f_a U_a, U the face's BRDF
    lobe (:func:`brdf_lobe`) integrated at the pixel's normal n_p = normalise(Σ f_a n_a)
    (U_p) and at the corners' n_a (U_a): the visibility ratio U_p F/U where F ≤ U, F
    + U_p − U where F > U. F alone where the corners' ``vertex_lobe`` rows are not one
    row ≥ 0 or n_p·ωo ≤ 0; v = 1 where U ≤ 1e-6 U_p. ``turn``: the map's 3×3
    map-to-world rotation; ``wo`` (P, 3) unit."""
    bary = np.asarray(bary, np.float64)
    view = np.asarray(view, np.int64)
    base = tables.first[corner].astype(np.int64)
    stored = tables.first[corner + 1] - base                                  # (P, 3)
    slots = tables.count[corner].max(axis=1)
    stack = [np.asarray(level, np.float64) for level in tables.stack]
    vw = np.asarray(view_weight, np.float64)
    out = np.zeros((len(corner), 3))
    for s in range(SLOTS):
        row = np.where(stored > 0, base + np.where(stored > s, s, 0), 0)
        lobe = tables.lobes[row[:, :, None], view[:, None, :]].astype(np.float64)
        keep = (stored > s) & (slots > s)[:, None]                           # (P, 3)
        w = np.einsum("pb,pabc->pac", vw, lobe[..., 0:3]) * keep[..., None]
        mu = np.einsum("pb,pabc->pac", vw, lobe[..., 3:6])
        if lambda_blend == "log":
            lam = np.exp(np.einsum("pb,pab->pa", vw, np.log(lobe[..., 6])))
        else:
            lam = np.einsum("pb,pab->pa", vw, lobe[..., 6])
        length = np.linalg.norm(mu, axis=2)
        ok = (stored > 0) & (slots > s)[:, None] & (length > 0)
        p, a = np.nonzero(ok)
        mu_map = (mu[p, a] / length[p, a, None]) @ turn
        f = sg.env_integral(stack, tables.levels, mu_map, lam[p, a], w[p, a])
        np.add.at(out, p, bary[p, a, None] * f)
    if tables.lobe_table is None or tables.vertex_lobe is None or tables.normals is None:
        return out
    m = tables.vertex_lobe[corner]                                            # (P, 3)
    n = np.asarray(tables.normals, np.float64)[corner]                        # (P, 3, 3)
    wo = np.asarray(wo, np.float64)
    npix = np.einsum("pa,pac->pc", bary, n)
    length = np.linalg.norm(npix, axis=1)
    use = (slots > 0) & (m[:, 0] >= 0) & (m[:, 1] == m[:, 0]) & (m[:, 2] == m[:, 0]) \
        & (length > 0) & (np.sum(npix * wo, axis=1) > 0)
    idx = np.flatnonzero(use)
    if not len(idx):
        return out
    table = np.asarray(tables.lobe_table, np.float64)

    def unshadowed(normal: np.ndarray, rows: np.ndarray) -> np.ndarray:
        mu, lam, a = np.zeros((len(rows), 3)), np.ones(len(rows)), np.zeros(len(rows))
        for k in np.unique(m[rows, 0]):
            sel = m[rows, 0] == k
            mu[sel], lam[sel], a[sel] = brdf_lobe(table[k], normal[sel], wo[rows[sel]])
        u = sg.env_integral(stack, tables.levels, mu @ turn, lam, np.repeat(a[:, None], 3, 1))
        return np.where(a[:, None] > 0, u, 0.0)

    up = unshadowed(npix[idx] / length[idx, None], idx)
    ua = sum(bary[idx, c, None] * unshadowed(n[idx, c], idx) for c in range(3))
    ok = (ua > 1e-6 * up) & (ua > 0)
    v = np.where(ok, np.minimum(out[idx] / np.where(ok, ua, 1.0), 1.0), 1.0)
    out[idx] += v * (up - ua)
    return out


def visibility_glossy(tables: SgTables, corner: np.ndarray, bary: np.ndarray,
                      wo: np.ndarray, turn: np.ndarray, light_sh: np.ndarray,
                      seen: np.ndarray | None = None) -> np.ndarray:
    """The glossy radiance (P, 3) of decision 0046 (visibility.glossy) of pixels whose
    corners share one table row ≥ 0 and whose blended normal n_p faces ``wo`` (0
    elsewhere); the occluders' radiance from ``light_sh`` (n², 3); the map turned by
    ``turn``, what the vertices see of its sources ``seen`` (V, K) (:func:`source_seen`;
    needed where there are sources)."""
    corner = np.asarray(corner, np.int64)
    bary = np.asarray(bary, np.float64)
    m = tables.vertex_lobe[corner]
    n = np.asarray(tables.normals, np.float64)[corner]
    wo = np.asarray(wo, np.float64)
    npix = np.einsum("pa,pac->pc", bary, n)
    length = np.linalg.norm(npix, axis=1)
    use = (m[:, 0] >= 0) & (m[:, 1] == m[:, 0]) & (m[:, 2] == m[:, 0]) & (length > 0) \
        & (np.sum(npix * wo, axis=1) > 0)
    unit = npix / np.maximum(length, 1e-300)[:, None]
    mu, lam = np.tile([0.0, 0.0, 1.0], (len(corner), 1)), np.ones(len(corner))
    weights, specular = np.zeros((len(corner), visibility.NODES)), np.zeros((len(corner), 3))
    table = np.asarray(tables.lobe_table, np.float64)
    for k in np.unique(m[use, 0]):
        sel = np.flatnonzero(use & (m[:, 0] == k))
        mu[sel], lam[sel], _ = brdf_lobe(table[k], unit[sel], wo[sel])
        weights[sel] = visibility.node_weights(np.asarray(tables.node_table[k], np.float64),
                                               np.sum(unit[sel] * wo[sel], axis=1))
        specular[sel] = np.asarray(tables.lobe_specular, np.float64)[k]
    occluder = vertex_diffuse(tables.occluder.astype(np.float64), light_sh)
    sources, brdf_cos = light_sources(tables), None
    stack = [np.asarray(level, np.float64) for level in
             (tables.stack if sources is None else tables.residual_stack)]
    if sources is not None:
        world = sources[:, :3].astype(np.float64) @ np.asarray(turn, np.float64).T
        brdf_cos = visibility.source_brdf(tables.glossy_brdfs, np.maximum(m[:, 0], 0), unit,
                                          wo, world)
    return visibility.glossy(tables.visibility, tables.visibility_resolution, occluder,
                             corner, bary, unit, mu, lam, weights, specular, stack,
                             tables.levels, turn, sources, brdf_cos, seen)


def light_sources(tables: SgTables) -> np.ndarray | None:
    """The tables' bright sources (K, 7) where ``normal=visibility`` can use them (their
    residual stack and the glossy BRDFs loaded; decision 0048), else None: the nodes
    take the whole map."""
    if tables.sources is None or not len(tables.sources) or tables.residual_stack is None \
            or tables.glossy_brdfs is None:
        return None
    return tables.sources


def vertex_diffuse(transfer: np.ndarray, light_sh: np.ndarray,
                   extra: np.ndarray | None = None) -> np.ndarray:
    """The vertices' diffuse radiance D (V, 3) = max(0, Σ_k transfer[v, c, k]
    light_sh[k, c] + extra[v, c]) (without the light's scale; ``extra``: the sources'
    change, :func:`source_diffuse`). A truncated SH product can ring below zero next to
    a bright window's shadow (Grace at order 5: whole patches of the bunny and the
    ground); radiance cannot, so D is clamped, as PRT renderers do."""
    d = np.einsum("vck,kc->vc", transfer, light_sh)
    return np.maximum(d if extra is None else d + extra, 0.0)


def map_turn(to_world: np.ndarray | None) -> Any:
    """The device buffer of Rᵀ (3×3 float32, row-major) for a map turned by the
    map-to-world rotation ``to_world`` (None: unturned): the kernels take world
    directions into the map by it (kernels/envmap.h ``envmap_into_map``)."""
    turn = np.eye(3) if to_world is None else np.asarray(to_world, np.float64)
    return cl.read_only_buffer(np.ascontiguousarray(turn.T, np.float32))


@dataclass
class SgDevice:
    """The tables on the OpenCL device, uploaded once (with ``lambda_blend="log"`` the
    lobes' last field holds log λ, as the kernel blends it); ``shade`` runs
    ``sg_shade``. ``normal``: ``vertex`` the paper's lobes as fitted, ``pixel`` each
    vertex's lobes turned towards the pixel's normal (PIXEL_NORMAL = 1; needs
    ``tables.normals``, else as ``vertex``; decision 0039), ``ratio`` the BRDF at the
    pixel's normal by the ratio of unshadowed radiances (BRDF_RATIO = 1; needs
    ``tables.normals`` and its lobe tables, else as ``vertex``; decision 0042),
    ``visibility`` no lobes, the BRDF at the pixel's normal against the vertices'
    visibility (kernel ``sg_shade_visibility``; needs the tables' visibility, else as
    ``vertex``; decision 0046)."""

    tables: SgTables
    lambda_blend: str = "log"
    normal: str = "vertex"
    buffers: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = self.tables
        flat, info = sg.pack_stack(t.stack)
        lobes = t.lobes
        if self.lambda_blend == "log":  # the kernel blends log λ: taken once, here
            lobes = lobes.copy()
            lobes[..., 6] = np.log(lobes[..., 6])
        self.turning = self.normal == "pixel" and t.normals is not None
        self.ratio = self.normal == "ratio" and t.normals is not None \
            and t.lobe_table is not None and t.vertex_lobe is not None
        self.visible = self.normal == "visibility" and t.normals is not None \
            and t.lobe_table is not None and t.vertex_lobe is not None \
            and t.visibility is not None and t.occluder is not None \
            and t.node_table is not None
        lobed = self.ratio or self.visible
        normals = t.normals if self.turning or lobed else np.zeros((1, 3), np.float32)
        table = t.lobe_table if lobed and t.lobe_table.size \
            else np.zeros((1, TABLE, 3), np.float32)  # no glossy material: a dummy row
        vertex_lobe = t.vertex_lobe if lobed else np.full(1, -1, np.int32)
        if self.visible:
            self.sources = light_sources(t)
            if self.sources is not None:  # the nodes take the map less its sources
                flat = sg.pack_stack(t.residual_stack)[0]
            self.buffers = {name: cl.read_only_buffer(np.ascontiguousarray(array)) for
                            name, array in (
                ("maps", t.visibility), ("stack", flat), ("info", info),
                ("materials", pack_materials(t.glossy_brdfs or [])),
                ("normals", normals), ("lobe_table", np.asarray(table, np.float32)),
                ("node_table", np.asarray(t.node_table, np.float32) if t.node_table.size
                 else np.zeros((1, TABLE, visibility.NODES), np.float32)),
                ("lobe_specular", np.asarray(t.lobe_specular, np.float32).reshape(-1, 3)
                 if t.lobe_specular is not None and t.lobe_specular.size
                 else np.zeros((1, 3), np.float32)),
                ("vertex_lobe", np.asarray(vertex_lobe, np.int32)))}
            self.kernel = cl.kernel("sg_render.cl", "sg_shade_visibility",
                                    {"SG_LOBE_TABLE": TABLE})
            return
        self.buffers = {name: cl.read_only_buffer(array) for name, array in (
            ("lobes", lobes), ("first", t.first), ("count", t.count), ("stack", flat),
            ("info", info), ("normals", normals),
            ("lobe_table", np.ascontiguousarray(table, np.float32)),
            ("vertex_lobe", np.ascontiguousarray(vertex_lobe, np.int32)))}
        self.kernel = cl.kernel("sg_render.cl", "sg_shade",
                                {"LAMBDA_LOG": int(self.lambda_blend == "log"),
                                 "PIXEL_NORMAL": int(self.turning),
                                 "BRDF_RATIO": int(self.ratio), "SG_LOBE_TABLE": TABLE})

    def vertex_diffuse(self, light_sh: np.ndarray, occluder_sh: np.ndarray | None = None,
                       extra: np.ndarray | None = None) -> Any:
        """A device buffer of :func:`vertex_diffuse` (V, 3) float32 (``extra``: the
        sources' change); with ``visibility`` (V, 6): then the occluders' radiance under
        ``occluder_sh`` (default ``light_sh``)."""
        d = vertex_diffuse(self.tables.transfer, light_sh.astype(np.float32), extra)
        if self.visible:
            sh_o = light_sh if occluder_sh is None else occluder_sh
            d = np.concatenate([d, vertex_diffuse(self.tables.occluder,
                                                  sh_o.astype(np.float32))], axis=1)
        return cl.read_only_buffer(np.ascontiguousarray(d, np.float32))

    def shade(self, pixels: dict[str, Any], n: int, vertex_diffuse: Any,
              to_world: np.ndarray | None, scale: float, out_buffer: Any | None = None,
              seen: np.ndarray | None = None) -> tuple[np.ndarray | None, float]:
        """Radiance (n, 3) float32 of the pixels whose per-camera device buffers are
        ``pixels`` (corner, bary, view, view_weight, wo), with the vertices' diffuse
        radiance ``vertex_diffuse`` (:meth:`vertex_diffuse`), the map turned by
        ``to_world`` (3×3, None: unturned), what the vertices see of the bright sources
        ``seen`` (V, K) (:func:`source_seen`; with ``visibility`` where there are
        sources), and the kernel's milliseconds. With
        ``out_buffer`` (≥ n · 12 bytes on the device) the radiance stays there and None is
        returned in its place."""
        b, levels = self.buffers, self.tables.levels
        out = None if out_buffer is not None else np.empty((n, 3), np.float32)
        if self.visible:
            resolution = self.tables.visibility_resolution
            ms = cl.run(self.kernel, n, b["maps"], np.int32(resolution),
                        np.int32(self.tables.visibility.shape[1]),
                        np.int32(len(visibility.level_offsets(resolution)) - 1),
                        vertex_diffuse, pixels["corner"], pixels["bary"], b["normals"],
                        pixels["wo"], b["lobe_table"], b["node_table"], b["lobe_specular"],
                        b["vertex_lobe"],
                        b["stack"], b["info"], np.int32(levels.count),
                        np.float32(np.log(levels.sigma0)),
                        np.float32(1.0 / np.log(levels.ratio)), map_turn(to_world),
                        cl.read_only_buffer(sources_to_world(
                            np.zeros((1, SOURCE_FIELDS)) if self.sources is None
                            else self.sources, to_world)),
                        np.int32(0 if self.sources is None else len(self.sources)),
                        cl.read_only_buffer(np.zeros(1, np.float32) if self.sources is None
                                            else np.ascontiguousarray(seen, np.float32)),
                        b["materials"], np.float32(scale), np.int32(n), out=out,
                        writes=12 * n, out_buffer=out_buffer, local=WORK_GROUP)
            return out, ms
        ms = cl.run(self.kernel, n, b["lobes"], b["first"], b["count"], vertex_diffuse,
                    np.int32(self.tables.lobes.shape[1]), pixels["corner"], pixels["bary"],
                    pixels["view"], pixels["view_weight"], b["normals"], pixels["wo"],
                    b["lobe_table"], b["vertex_lobe"], b["stack"], b["info"],
                    np.int32(levels.count), np.float32(np.log(levels.sigma0)),
                    np.float32(1.0 / np.log(levels.ratio)), map_turn(to_world),
                    np.float32(scale), np.int32(n), out=out,
                    writes=12 * n, out_buffer=out_buffer, local=WORK_GROUP)
        return out, ms


def shade_arrays(device: SgDevice, corner: np.ndarray, bary: np.ndarray, view: np.ndarray,
                 view_weight: np.ndarray, light_sh: np.ndarray,
                 to_world: np.ndarray | None = None, scale: float = 1.0,
                 wo: np.ndarray | None = None, about_y: float | None = None) -> np.ndarray:
    """The kernel on host arrays (as :func:`shade_numpy`'s arguments; ``wo`` (P, 3) is
    needed where the device turns lobes), float32 (P, 3)."""
    if wo is None:
        if device.turning or device.ratio or device.visible:
            raise ValueError(f"shade_arrays: normal={device.normal!r} needs the directions wo")
        wo = np.zeros((1, 3))
    pixels = {"corner": cl.read_only_buffer(np.asarray(corner, np.int32)),
              "bary": cl.read_only_buffer(np.asarray(bary, np.float32)),
              "view": cl.read_only_buffer(np.asarray(view, np.int32)),
              "view_weight": cl.read_only_buffer(np.asarray(view_weight, np.float32)),
              "wo": cl.read_only_buffer(np.ascontiguousarray(wo, np.float32))}
    turn = np.eye(3) if to_world is None else to_world
    seen = source_seen(device.tables, turn, about_y) if device.visible else None
    extra = source_diffuse(device.tables, turn, about_y, seen) if device.visible else None
    return device.shade(pixels, len(corner), device.vertex_diffuse(light_sh, extra=extra),
                        to_world, scale, seen=seen)[0]


def kernel_bytes(tables: SgTables, corner: np.ndarray, turning: bool = False,
                 ratio: bool = False, visible: bool = False) -> int:
    """Bytes ``sg_shade`` loads and stores for these pixels, every gathered load counted
    (cache hits included): per pixel 4 × 12 B of indices and weights, 3 counts, per
    active slot 9 lobes × 28 B and 2 levels × 4 texels × 12 B (``ratio``: 3 × the
    texels, one lookup per corner), 3 vertices' diffuse radiance × 12 B, 12 B out;
    ``turning`` (PIXEL_NORMAL): per pixel with a slot ω_o and 3 normals, 4 × 12 B;
    ``ratio`` (BRDF_RATIO): per pixel with a slot also 3 × 4 B of table rows, 4 BRDF
    lobes × 2 table rows × 12 B and 4 lookups × 2 levels × 4 texels × 12 B;
    ``visible`` (sg_shade_visibility): per pixel 36 B in (indices, weights, ω_o), 3 ×
    (4 + 12 + 12) B of table rows, normals and diffuse light, 12 B out; per pixel on a
    glossy face (its corners' table row ≥ 0) also 2 lobe-table rows × 12 B, 2 node-table
    rows × 28 B, ρs 12 B, 7 lookups × 2 levels × 4 texels × 12 B, 3 × 7 visibility
    lookups × 2 levels × 4 texels × 1 B and 3 occluder radiances × 12 B, and per bright
    source (decision 0048) its 28 B, the material's 64 B row and its 3 corners' view of
    it, 3 × 4 B (decision 0049)."""
    if visible:
        corner = np.asarray(corner, np.int64)
        lobed = 0 if tables.vertex_lobe is None else \
            int(np.count_nonzero(tables.vertex_lobe[corner[:, 0]] >= 0))
        found = light_sources(tables)
        glossy = 2 * 12 + 2 * 28 + 12 + 7 * 2 * 4 * 12 + 21 * 2 * 4 + 3 * 12 \
            + (0 if found is None else len(found) * (28 + 64 + 3 * 4))
        return int(len(corner) * (36 + 3 * 28 + 12) + lobed * glossy)
    slots = tables.count[np.asarray(corner, np.int64)].max(axis=1).astype(np.int64)
    per_pixel = 48 + 3 + 3 * 12 + 12
    active = int(np.count_nonzero(slots))
    extra = 48 * active if turning or ratio else 0
    if ratio:
        extra += active * (12 + 4 * 2 * 12 + 4 * 2 * 4 * 12)
    lookups = 3 if ratio else 1
    return int(len(corner) * per_pixel + extra
               + slots.sum() * (9 * FIELDS * 4 + lookups * 2 * 4 * 12))


# -------------------------------------------------------------------------- frames


@dataclass
class SgGBuffer:
    """One camera's pixels: ``pixel`` (P,) flat indices that hit, their face's vertices
    ``corner`` (P, 3) and barycentrics ``bary`` (P, 3), view triangles ``view`` (P, 3)
    and ``view_weight`` (P, 3), ``wo`` (P, 3) float32 the unit directions to the eye
    (−ray direction); ``miss_pixel``/``miss_direction`` (M, 3) world ray
    directions of the others; the milliseconds it took; ``back`` (P,) whether the pixel
    sees the back of its face and ``face`` (P,) the face."""

    pixel: np.ndarray
    corner: np.ndarray
    bary: np.ndarray
    view: np.ndarray
    view_weight: np.ndarray
    miss_pixel: np.ndarray
    miss_direction: np.ndarray
    trace_ms: float
    view_lookup_ms: float
    back: np.ndarray
    face: np.ndarray
    wo: np.ndarray
    device: dict[str, Any] = field(default_factory=dict)

    def buffers(self) -> dict[str, Any]:
        """Device copies of the per-pixel arrays (made on first use)."""
        if not self.device:
            self.device = {name: cl.read_only_buffer(getattr(self, name)) for name in
                           ("corner", "bary", "view", "view_weight", "wo",
                            "miss_direction")}
            self.device.update({name: cl.read_only_buffer(getattr(self, name).astype(np.int32))
                                for name in ("pixel", "miss_pixel")})
        return self.device


def camera_gbuffer(tracer: RayTracer, vertices: np.ndarray, faces: np.ndarray, cam: Any
                   ) -> SgGBuffer:
    """Trace camera ``cam``'s rays; hits' faces and barycentrics, view triangles of
    ω_o = −ray direction (kernel ``sg_view_lookup``)."""
    t0 = time.perf_counter()
    origins, directions = aligned_image_rays(cam)
    hits = tracer.intersect(origins, directions)
    hit = hits.prim >= 0
    u, v = hits.u[hit], hits.v[hit]
    corner = np.ascontiguousarray(faces[hits.prim[hit]], np.int32)
    bary = np.ascontiguousarray(np.stack([1.0 - u - v, u, v], axis=1), np.float32)
    trace_ms = (time.perf_counter() - t0) * 1e3
    wo = np.ascontiguousarray(-directions[hit], np.float32)
    view, view_weight, lookup_ms = device_view_triangles(wo)
    a, b, c = (np.asarray(vertices, np.float64)[corner[:, k]] for k in range(3))
    back = sees_back(directions[hit], np.cross(b - a, c - a))
    return SgGBuffer(np.flatnonzero(hit), corner, bary, view, view_weight,
                     np.flatnonzero(~hit), np.ascontiguousarray(directions[~hit]),
                     trace_ms, lookup_ms, back, hits.prim[hit], wo)


class SgRenderer:
    """Method sg's frames over loaded tables (pipeline/render/__init__.py ``Renderer``):
    each frame traces its scene's camera, reads the environment's rotation and scale,
    and shades (timings: gbuffer (trace + view lookup), sh (SH rotation and the
    vertices' diffuse radiance), shade, background). ``component`` (one of
    :data:`COMPONENTS`): ``all``, or the reflected light of one part, ``glossy`` (the
    lobes) or ``diffuse`` (the SH term), without the background (as ``prt reference
    --lobe``). With ``face_object`` (F,), a frame notes the objects whose pixels see the
    backs of faces (:func:`pipeline.render.back_face_notes`).

    Caches: ``gbuffers`` the last camera's G-buffer, ``images`` the last image size's
    device image, ``static`` the map's device buffer."""

    def __init__(self, tables: SgTables, vertices: np.ndarray, faces: np.ndarray,
                 env_map: np.ndarray, lambda_blend: str = "log", component: str = "all",
                 face_object: np.ndarray | None = None, normal: str = "visibility") -> None:
        if normal not in NORMALS:
            raise PrtError("--option", f"normal={normal!r}: expected one of "
                           f"{', '.join(NORMALS)}")
        if lambda_blend not in LAMBDA_BLENDS:
            raise PrtError("--option", f"lambda_blend={lambda_blend!r}: expected one of "
                           f"{', '.join(LAMBDA_BLENDS)}")
        if component not in COMPONENTS:
            raise PrtError("--option", f"component={component!r}: expected one of "
                           f"{', '.join(COMPONENTS)}")
        if component == "diffuse":  # no lobe slot runs, no glossy material
            tables = replace(tables, count=np.zeros_like(tables.count),
                             vertex_lobe=None if tables.vertex_lobe is None
                             else np.full_like(tables.vertex_lobe, -1))
        self.tables, self.vertices, self.faces = tables, vertices, faces
        self.component, self.face_object = component, face_object
        self.tracer = RayTracer(vertices, faces)
        self.device = SgDevice(tables, lambda_blend, normal)
        self.env_map = np.ascontiguousarray(env_map, np.float32)
        order = int(round(np.sqrt(tables.transfer.shape[2])))  # sg.diffuse_order
        self.map_sh = sh.project_latlong(self.env_map, order=order)  # (order², 3), unrotated
        self.occluder_sh = self.map_sh  # the occluders' light (normal=visibility)
        if component == "glossy":
            self.map_sh = np.zeros_like(self.map_sh)
        self.static: dict[str, Any] = {}
        self.gbuffers: dict[tuple, SgGBuffer] = {}
        self.images: dict[int, DeviceImage] = {}

    def edit_mode(self, kind: str, scene: Scene) -> Callable[[Scene], Frame]:
        """Every edit takes the one frame path (the camera's G-buffer is kept)."""
        return self.frame

    def frame(self, scene: Scene) -> Frame:
        env_map = self.env_map
        t0 = time.perf_counter()
        cam = scene.camera
        key = camera_key(cam)
        was_cached = key in self.gbuffers
        if not was_cached:
            self.gbuffers.clear()
            self.gbuffers[key] = camera_gbuffer(self.tracer, self.vertices, self.faces, cam)
        gbuffer = self.gbuffers[key]
        pixels = gbuffer.buffers()
        t1 = time.perf_counter()
        env = scene.environment
        to_world, scale = env.to_world, env.scale
        about_y = env.turn_about_y
        light_sh = sh.rotate_y(self.map_sh, about_y) if about_y is not None \
            else sh.rotate(self.map_sh, to_world)
        occluder_sh = None
        if self.device.visible and self.component == "glossy":
            occluder_sh = sh.rotate_y(self.occluder_sh, about_y) if about_y is not None \
                else sh.rotate(self.occluder_sh, to_world)
        seen = source_seen(self.tables, to_world, about_y) if self.device.visible else None
        extra = source_diffuse(self.tables, to_world, about_y, seen) \
            if self.device.visible and self.component != "glossy" else None
        vertex_diffuse = self.device.vertex_diffuse(light_sh, occluder_sh, extra)
        t2 = time.perf_counter()
        # shading, background and their scatter stay on the device (render.DeviceImage)
        image = DeviceImage.of_size(self.images, cam.width * cam.height)
        shade_ms = background_ms = scatter_ms = 0.0
        background = len(gbuffer.miss_pixel) > 0 and self.component == "all"
        if not background:  # the pixels that miss stay black
            image.clear()
        if len(gbuffer.pixel):
            shaded = cl.scratch_buffer(image.buffers, "shaded", 12 * len(gbuffer.pixel))
            _, shade_ms = self.device.shade(pixels, len(gbuffer.pixel), vertex_diffuse,
                                            to_world, scale, out_buffer=shaded, seen=seen)
            scatter_ms += image.scatter(shaded, pixels["pixel"], len(gbuffer.pixel))
        if background:
            if "map" not in self.static:
                self.static["map"] = cl.read_only_buffer(env_map)
            miss = cl.scratch_buffer(image.buffers, "miss", 12 * len(gbuffer.miss_pixel))
            background_ms = cl.run(cl.kernel("sg_render.cl", "sg_background"),
                                   len(gbuffer.miss_pixel), self.static["map"],
                                   np.int32(env_map.shape[1]), np.int32(env_map.shape[0]),
                                   pixels["miss_direction"], map_turn(to_world),
                                   np.float32(scale),
                                   np.int32(len(gbuffer.miss_pixel)), out=None,
                                   writes=12 * len(gbuffer.miss_pixel), out_buffer=miss,
                                   local=WORK_GROUP)
            scatter_ms += image.scatter(miss, pixels["miss_pixel"], len(gbuffer.miss_pixel))
        rgb = image.read()
        t3 = time.perf_counter()
        timings = {"gbuffer_ms": (t1 - t0) * 1e3, "gbuffer_cached": float(was_cached),
                   "trace_ms": 0.0 if was_cached else gbuffer.trace_ms,
                   "view_lookup_ms": 0.0 if was_cached else gbuffer.view_lookup_ms,
                   "sh_ms": (t2 - t1) * 1e3, "shade_ms": shade_ms,
                   "background_ms": background_ms, "scatter_ms": scatter_ms,
                   "kernel_ms": shade_ms + background_ms + scatter_ms,
                   "counted_kernel_ms": shade_ms, "setup_ms": (t2 - t0) * 1e3,
                   "total_ms": (t3 - t0) * 1e3}
        notes = [] if self.face_object is None else back_face_notes(
            "sg", gbuffer.back, self.face_object[gbuffer.face], list(scene.objects))
        return Frame("sg", rgb.reshape(cam.height, cam.width, 3), timings, notes,
                     kernel_bytes=kernel_bytes(self.tables, gbuffer.corner,
                                                 self.device.turning, self.device.ratio,
                                                 self.device.visible))


def sg_renderer(scene: Scene, artifacts: Mapping[str, Artifact], lambda_blend: str = "log",
                component: str = "all", normal: str = "visibility") -> SgRenderer:
    """The method's renderer factory (pipeline/method.py): tables loaded once from the
    artifacts of ``geometry``, ``sg.relax``, ``sg.diffuse``, ``sg.env_prefilter``; the
    map for the background and the SH lighting from the scene's environment file."""
    if normal in NORMALS and normal != "visibility" and "sg.relax" not in artifacts:
        raise PrtError("sg.relax", f"normal={normal} renders the fitted lobes: not given")
    geo = artifacts["geometry"]
    vertices, faces = geo.read("vertices"), np.asarray(geo.read("faces"), np.int64)
    tables = load_tables(artifacts, len(vertices))
    if normal in ("ratio", "visibility"):  # the glossy materials' BRDF lobes (0042)
        tables = replace(tables, **scene_lobe_tables(scene, geo, normal == "visibility"))
    if normal == "visibility":  # the vertices' visibility (decision 0046)
        tables = replace(tables, **load_visibility(artifacts["sg.visibility"], len(vertices),
                                                   int(round(np.sqrt(tables.transfer.shape[2])))))
    env_map = read_environment(scene.environment.file)
    if normal == "visibility" and light_sources(tables) is not None:
        if "sg.source_visibility" in artifacts:  # decision 0049
            tables = replace(tables, **load_source_visibility(
                artifacts["sg.source_visibility"], len(vertices), len(tables.sources)))
        attrs = artifacts["sg.env_prefilter"].attrs
        tables = replace(tables, source_sh=sources_sh(
            env_map, float(attrs["source_quantile"]), float(attrs["source_min_share"]),
            int(round(np.sqrt(tables.transfer.shape[2])))),
            # float64 once here, not a copy of (V, 3, n²) in every frame's source_diffuse
            direct_transfer=None if tables.direct_transfer is None
            else np.asarray(tables.direct_transfer, np.float64))
    return SgRenderer(tables, vertices, faces, env_map, lambda_blend, component,
                     np.asarray(geo.read("face_object")), normal)


def sources_sh(env_map: np.ndarray, quantile: float, min_share: float, order: int
               ) -> np.ndarray:
    """The SH (order², 3) of the part of ``env_map`` its bright sources hold (map frame;
    pipeline/methods/sg/sources.py's split, as sg.env_prefilter made it)."""
    _, residual = split_sources(env_map, quantile, min_share)
    return sh.project_latlong(np.asarray(env_map, np.float64) - residual, order=order)


def source_diffuse(tables: SgTables, turn: np.ndarray, about_y: float | None,
                   seen: np.ndarray | None = None) -> np.ndarray | None:
    """What the sources change in the vertices' diffuse radiance (V, 3), float64 (None
    where there is nothing to change: no sources, or tables without the direct transfer,
    albedos or visibility): their direct light as the SH transfer holds it, blurred to
    order n, taken out, −Σ_k direct[v, c, k] S_k[c] (S the sources' SH turned with the
    map: ``about_y`` degrees about +y, or ``turn`` the map-to-world rotation), and put
    back sharp from what the vertices see of them (``seen``, default
    :func:`source_seen`),
    (kd_v/π) Σ_s P_s max(0, n_v·ω_s) S_v,s (decision 0048)."""
    found = light_sources(tables)
    if found is None or tables.direct_transfer is None or tables.vertex_albedo is None \
            or tables.source_sh is None or tables.normals is None:
        return None
    if seen is None:
        seen = source_seen(tables, turn, about_y)
    if seen is None:
        return None
    source_sh = sh.rotate_y(tables.source_sh, about_y) if about_y is not None \
        else sh.rotate(tables.source_sh, turn)
    out = -np.einsum("vck,kc->vc", np.asarray(tables.direct_transfer, np.float64), source_sh)
    normals = np.asarray(tables.normals, np.float64)
    kd = np.asarray(tables.vertex_albedo, np.float64)
    lit = np.flatnonzero(kd.max(axis=1) > 0)
    world = sources_to_world(found, turn).astype(np.float64)
    for k, source in enumerate(world):
        cosine = normals[lit] @ source[:3]
        up = lit[cosine > 0]
        out[up] += (kd[up] / np.pi) * ((cosine[cosine > 0] * seen[up, k])[:, None]
                                       * source[3:6])
    return out


def source_seen(tables: SgTables, turn: np.ndarray, about_y: float | None
                ) -> np.ndarray | None:
    """What each vertex sees of each bright source this frame, S (V, K) float64 in
    [0, 1] (None: no sources): its visibility filtered by the source's Gaussian. Read
    from sg.source_visibility's table where the map turns ``about_y`` degrees about +y
    (source_rings.py, decision 0049), else from the vertices' visibility maps at the
    sources' directions under ``turn`` (the map-to-world rotation), filtered over
    1/√λ_s (decision 0048; None without them)."""
    found = light_sources(tables)
    if found is None:
        return None
    if about_y is not None and tables.source_table is not None:
        return source_rings.at_turn(tables.source_table, tables.source_offsets,
                                    slice(None), about_y)
    if tables.visibility is None:
        return None
    world = sources_to_world(found, turn).astype(np.float64)
    count = len(tables.visibility)
    every = np.arange(count)
    return np.stack([visibility.lookup(tables.visibility, tables.visibility_resolution, every,
                                       np.broadcast_to(s[:3], (count, 3)),
                                       np.full(count, 1.0 / np.sqrt(s[6])))
                     for s in world], axis=1)
