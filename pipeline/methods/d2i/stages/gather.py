"""Stage ``gather``: paper 000 §5.1's gather samples, their areas, disks and sub-area
sample sets (one chunk: the whole scene). Schema ``gather``.

Gather samples (backward photon shooting, Hašan et al. 2006). A view sample x is a pixel
of the G-buffer; a ray leaves x and its first hit is a gather sample. Two groups:

* diffuse: x drawn uniformly among the pixels that see a surface, the direction uniform
  over x's hemisphere;
* glossy: x drawn among the pixels of glossy (non-Lambertian) materials, the direction
  drawn with density ∝ (ω·R)^e about R, the mirror reflection of the direction to the eye
  (paper eq. 16, e = ``gather.glossy_exponent``, default 200).

The group sizes are glossy : diffuse = ``gather.glossy_ratio`` (paper: 1 : 6); a scene
without glossy pixels gets diffuse samples only. Directions below x's shading horizon and
rays that escape are drawn again, up to ``MAX_RAYS_PER_SAMPLE`` rays per requested
sample: an open scene (a plane under the sky) may get fewer samples than requested, or
none, and then has less (or no) indirect light to gather; ``count`` says how many. A
gather sample's normal is the shading normal of the hit turned towards the ray's origin:
the side of the surface that was seen. The rays are Embree's or the device's BVH
kernel's (``bake.device``, pipeline/device/bake_tracer.py: the hits' barycentrics differ
in float32 rounding, a ray grazing an edge may hit the neighbouring face).

Order. Samples are sorted by object, then by the chart of their normal (its largest
component's axis and sign), then along a 2D Hilbert curve in that chart's plane
(pipeline/math/spacecurve.py, ``chart_order``), so that rows of T, D and Ms are smooth in
the gather index and runs of samples fill squares on planar surfaces.

Areas |A_g|. Stratified surface samples (``_surface_samples``), one on every triangle
plus more in proportion to area (``gather.area_samples`` per gather sample in all), each
carrying the area it stands for, are taken on both sides of the surface. Each is
assigned to the nearest of its ``NEIGHBOURS`` nearest gather samples on the same
object whose normal faces the same way (n_g · n_s > ``FACING``), that lies within
``REACH`` × g's local spacing (the distance from g to its ``SPACING_K``-th nearest
neighbour on the object) and whose shooting view sample (the pixel g's ray left from)
sees the surface sample. Surface samples with none are dropped: the insides of closed
meshes, the outsides of the Cornell box's walls, and regions no gather ray reaches (the
floor under a box, the ceiling behind the luminaire).
For a Poisson spread of gather samples the chance that a point of a sampled region lies
farther than the reach from every sample is ≈ exp(−4π·SPACING_K/3) ≈ 4e-6. The
visibility test removes the band around hidden regions that the reach alone lets in:
without it the floor kept a ≈ 20 mm band around each box's footprint, and at 64², 4096
gathers the floor's and the boxes' indirect light came out 6–7 % high against the
reference (with it: floor +1.7 %, boxes 0.4 %, walls 2–4 % low). |A_g| is the
sum of the areas assigned to g; the attribute ``dropped_area`` records what was dropped.
The estimate's scatter is the gather's weight in every product: measured on the Tableau
(64k gathers) as the spread between two seeds, ±40 % with 8 independent uniform samples
per gather (5.5 % of the gathers got none), ±12 % with 32 stratified ones (0.15 %).

Disks and sub-area samples. K_g is the disk of area |A_g| (radius √(|A_g|/π)) about g in
its tangent plane. Its sub-area samples are the shared unit-disk pattern ``disk_pattern``
(``gather.subarea_max`` points: the Halton (2, 3) sequence through the concentric
mapping, so that every prefix is evenly spread), turned by g's own angle
``disk_rotation`` and scaled by the radius: q_i = g + r (R(θ_g) p_i)·(t_g, b_g), with
t_g = ``disk_tangent`` and b_g = n_g × t_g.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from pipeline.device.bake_tracer import PARAM, bake_tracer
from pipeline.device.raytrace import RAY_EPSILON, Mesh, surface_at
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.math.brdf_sampling import cos_power_direction, frame_to_world
from pipeline.math.frames import tangent_from_normal
from pipeline.math.spacecurve import chart_order
from pipeline.methods.d2i.transfer import disk_pattern

NEIGHBOURS = 8     # gather samples considered for each surface sample
FACING = 0.5       # least n_g · n_s for a surface sample to join gather sample g
SPACING_K = 3      # a gather sample's local spacing: distance to its 3rd nearest neighbour
REACH = 2.0        # surface samples farther than REACH × spacing from g are dropped
MAX_RAYS_PER_SAMPLE = 64  # rays shot per requested sample before settling for fewer


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    geo = {n: ctx.inputs["geometry"].read(n) for n in
           ("vertices", "normals", "uv", "faces", "face_object", "object_material")}
    gbuf = ctx.inputs["gbuffer"]
    position = gbuf.read("position").reshape(-1, 3).astype(np.float64)
    normal = gbuf.read("normal").reshape(-1, 3).astype(np.float64)
    material = gbuf.read("material_id").reshape(-1)
    names = ctx.inputs["geometry"].attrs["material_names"]
    glossy_material = np.array([ctx.scene[f"materials.{n}.model"] != "lambert"
                                for n in names] + [False])
    seen = np.flatnonzero(material >= 0)
    glossy_pixels = seen[glossy_material[material[seen]]]

    count = int(ctx.params["gather.count"])
    ratio = float(ctx.params["gather.glossy_ratio"])
    n_glossy = int(round(count * ratio / (1.0 + ratio))) if len(glossy_pixels) else 0
    vertices = geo["vertices"].astype(np.float64)
    diagonal = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    tracer = bake_tracer(ctx.params[PARAM], ctx.inputs["geometry"].record["key"],
                         geo["vertices"], geo["faces"])
    cam = np.asarray(ctx.scene["camera"]["position"], np.float64)
    shoot = _Shooter(tracer, Mesh.from_arrays(geo), position, normal, cam,
                     RAY_EPSILON * diagonal, ctx.rng)
    diffuse = shoot(seen, count - n_glossy, exponent=None)
    glossy = shoot(glossy_pixels, n_glossy, exponent=float(ctx.params["gather.glossy_exponent"]))
    samples = {k: np.concatenate([diffuse[k], glossy[k]]) for k in diffuse}
    samples["group"] = np.r_[np.zeros(len(diffuse["face"]), np.int8),
                             np.ones(len(glossy["face"]), np.int8)]
    found = len(samples["face"])

    order = chart_order(samples["position"], samples["normal"], samples["object_id"],
                        vertices.min(0), vertices.max(0))
    samples = {k: v[order] for k, v in samples.items()}
    source = samples["source_pixel"]
    seen_from = position[source] + RAY_EPSILON * diagonal * normal[source]
    area, dropped = _areas(samples["position"], samples["normal"], samples["object_id"],
                           vertices, geo["faces"], geo["face_object"],
                           int(ctx.params["gather.area_samples"]) * count, ctx.rng,
                           _Seen(tracer, seen_from, RAY_EPSILON * diagonal))
    subarea_max = int(ctx.params["gather.subarea_max"])
    if subarea_max & (subarea_max - 1):
        raise PrtError(None, f"gather.subarea_max = {subarea_max}: expected a power of two")
    area32 = area.astype(np.float32)
    ctx.meta.update({"dropped_area": float(dropped), "requested": int(count),
                     "count": len(area32), "glossy_count": int(samples["group"].sum()),
                     "total_area": float(area32.sum(dtype=np.float64))})
    return {
        "position": samples["position"].astype(np.float32),
        "normal": samples["normal"].astype(np.float32),
        "object_id": samples["object_id"].astype(np.int32),
        "material_id": geo["object_material"][samples["object_id"]].astype(np.int32),
        "face": samples["face"].astype(np.int32),
        "group": samples["group"],
        "source_pixel": samples["source_pixel"].astype(np.int32),
        "area": area32,
        "radius": np.sqrt(area / np.pi).astype(np.float32),
        "disk_tangent": tangent_from_normal(samples["normal"]).astype(np.float32),
        "disk_rotation": ctx.rng.uniform(0.0, 2.0 * np.pi, found).astype(np.float32),
        "disk_pattern": disk_pattern(subarea_max).astype(np.float32),
    }


class _Shooter:
    """Draws gather samples: rays from view samples, first hits kept."""

    def __init__(self, tracer, mesh, position, normal, eye, epsilon, rng) -> None:
        self.tracer, self.mesh, self.rng, self.epsilon = tracer, mesh, rng, epsilon
        self.position, self.normal, self.eye = position, normal, eye

    def __call__(self, pool: np.ndarray, n: int, exponent: float | None) -> dict:
        """Up to ``n`` gather samples from view samples drawn from ``pool``; fewer when
        ``MAX_RAYS_PER_SAMPLE`` × n rays find fewer hits (open scenes)."""
        parts: list[dict] = [self._shoot(pool[:0], exponent)]
        have = shot = 0
        while have < n and shot < MAX_RAYS_PER_SAMPLE * n and len(pool):
            pixel = self.rng.choice(pool, max(int((n - have) * 1.25), 1024))
            parts.append(self._shoot(pixel, exponent))
            have += len(parts[-1]["face"])
            shot += len(pixel)
        return {k: np.concatenate([p[k] for p in parts])[:n] for k in parts[0]}

    def _shoot(self, pixel: np.ndarray, exponent: float | None) -> dict:
        x, nx = self.position[pixel], self.normal[pixel]
        u = self.rng.random((len(pixel), 2))
        if exponent is None:  # uniform over the hemisphere about the normal
            d = frame_to_world(cos_power_direction(u[:, 0], u[:, 1], 0.0), nx)
        else:  # ∝ (ω·R)^e about the mirror direction R of the view direction
            wo = self.eye - x
            wo /= np.linalg.norm(wo, axis=1, keepdims=True)
            mirror = 2.0 * np.sum(wo * nx, 1, keepdims=True) * nx - wo
            d = frame_to_world(cos_power_direction(u[:, 0], u[:, 1], exponent), mirror)
        above = np.sum(d * nx, axis=1) > 0.0
        hits = self.tracer.intersect(x + self.epsilon * nx, d)
        ok = above & (hits.prim >= 0)
        surface = surface_at(self.mesh, hits.select(ok), x[ok], d[ok], normal_dtype=np.float64)
        return {"position": surface.position, "normal": surface.normal, "face": surface.face,
                "object_id": surface.object_id, "source_pixel": pixel[ok]}


class _Seen:
    """Whether surface points are visible from the view samples their gather samples were
    shot from (``origin`` (G, 3), already offset off the surface)."""

    def __init__(self, tracer: Any, origin: np.ndarray, epsilon: float) -> None:
        self.tracer, self.origin, self.epsilon = tracer, origin, epsilon

    def __call__(self, gather: np.ndarray, point: np.ndarray, normal: np.ndarray
                 ) -> np.ndarray:
        start = point + self.epsilon * normal
        ray = self.origin[gather] - start
        length = np.linalg.norm(ray, axis=1)
        ok = length > 0
        seen = np.zeros(len(point), bool)
        seen[ok] = ~self.tracer.occluded(start[ok], ray[ok] / length[ok, None],
                                         length[ok] * (1 - 1e-4))
        return seen


def _areas(position: np.ndarray, normal: np.ndarray, object_id: np.ndarray,
           vertices: np.ndarray, faces: np.ndarray, face_object: np.ndarray, total: int,
           rng: np.random.Generator, seen: _Seen) -> tuple[np.ndarray, float]:
    """|A_g| (G,) from two-sided uniform surface samples, and the area dropped."""
    p0, p1, p2 = (vertices[faces[:, i]] for i in range(3))
    cross = np.cross(p1 - p0, p2 - p0)
    face_area = 0.5 * np.linalg.norm(cross, axis=1)
    face_normal = cross / np.maximum(2.0 * face_area, 1e-300)[:, None]
    face, points, weight = _surface_samples(p0, p1, p2, face_area, total, rng)
    area = np.zeros(len(position))
    dropped = float(weight.sum() * 2.0)
    for obj in np.unique(object_id):
        own = np.flatnonzero(object_id == obj)
        mine = np.flatnonzero(face_object[face] == obj)
        if len(own) == 0 or len(mine) == 0:
            continue
        tree = cKDTree(position[own])
        k = min(NEIGHBOURS, len(own))
        spacing = tree.query(position[own], k=min(SPACING_K + 1, len(own)))[0]
        reach = REACH * np.atleast_2d(spacing)[:, -1] if len(own) > 1 else np.full(1, np.inf)
        dist, near = tree.query(points[mine], k=k)
        dist, near = dist.reshape(len(mine), k), near.reshape(len(mine), k)
        for side in (1.0, -1.0):
            n_side = side * face_normal[face[mine]]
            usable = (np.einsum("nkc,nc->nk", normal[own][near], n_side) > FACING) & \
                (dist <= reach[near])
            chosen = np.full(len(mine), -1)
            for j in range(k):  # nearest usable gather sample whose view sample sees it
                todo = np.flatnonzero((chosen < 0) & usable[:, j])
                if len(todo) == 0:
                    continue
                ok = seen(own[near[todo, j]], points[mine][todo], n_side[todo])
                chosen[todo[ok]] = near[todo[ok], j]
            assigned = chosen >= 0
            kept = np.bincount(chosen[assigned], weights=weight[mine][assigned],
                               minlength=len(own))
            area[own] += kept
            dropped -= float(kept.sum())
    return area, dropped


R2_STEP = 1.0 / np.array([1.32471795724474602596, 1.32471795724474602596 ** 2])
"""Step of the R2 sequence (Roberts 2018; the plastic number's powers): the 2D
sequence u_i = frac(u_0 + i·R2_STEP) spreads any number of points evenly."""


def _surface_samples(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, face_area: np.ndarray,
                     total: int, rng: np.random.Generator
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """About ``total`` stratified surface samples: (face (S,), point (S, 3), the area each
    stands for (S,)). Every face gets one, the rest go in proportion to area by
    systematic sampling (each face ⌊n_f⌋ or ⌈n_f⌉ of its expected n_f); within a face the
    points follow the R2 sequence from a random start, folded into the triangle
    (u + v > 1 ↦ (1 − u, 1 − v): uniform, and the fold keeps the spread).

    Stratified, the share of samples that fall in a gather sample's cell varies far less
    than with independent uniform points (the scatter measured on the Tableau: module
    docstring). Each gather's area is its weight in every product, so the scatter is
    noise in every product (and likely the speckle once seen in narrow glossy
    reflections; not isolated)."""
    extra = max(total - len(face_area), 0)
    expected = np.cumsum(extra * face_area / face_area.sum())
    per_face = 1 + np.diff(np.floor(np.r_[0.0, expected] + rng.random())).astype(np.int64)
    face = np.repeat(np.arange(len(face_area)), per_face)
    first = np.cumsum(per_face) - per_face
    index = np.arange(len(face)) - first[face]
    u = np.mod(rng.random((len(face_area), 2))[face] + index[:, None] * R2_STEP, 1.0)
    folded = u.sum(axis=1) > 1.0
    u[folded] = 1.0 - u[folded]
    points = p0[face] + u[:, :1] * (p1 - p0)[face] + u[:, 1:] * (p2 - p0)[face]
    return face, points, face_area[face] / per_face[face]


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"gather": max(int(ctx.params["gather.count"]), 1)})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    meta = metas[0][1]
    return Output({
        "count": meta["count"], "requested": meta["requested"],
        "glossy_count": meta["glossy_count"],
        "glossy_exponent": float(ctx.params["gather.glossy_exponent"]),
        "subarea_max": int(ctx.params["gather.subarea_max"]),
        "total_area": meta["total_area"], "dropped_area": meta["dropped_area"]})
