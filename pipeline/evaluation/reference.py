"""The Monte-Carlo reference renderer: progressive path tracing with Embree and MIS.

It shares the project's geometry (the ``geometry`` artifact: world-space triangles,
vertex normals, uv), BRDFs (pipeline/math/brdf.py, sampled by brdf_sampling.py), camera
(pipeline/math/camera.py), lights (pipeline/math/lights.py layout) and environment maps
(pipeline/math/envmap.py), so that each method is measured against the same transport.

Transports (what a path may carry):

``direct``      emission seen by the camera, plus light from every scene light reflected
                once by the first surface (no bounces).
``env-direct``  the environment seen by the camera and environment light reflected once,
                with visibility (other lights ignored).
``first-glossy`` paper 000's transport (what method d2i models): the first surface seen
                from the camera reflects with its full BRDF; every later vertex is
                Lambertian with its diffuse albedo kd (the glossy lobe dropped), any
                number of bounces.
``first-glossy-indirect`` the same paths without their direct part (no emission or
                environment seen from the camera or after one bounce, no light sampled
                at the first vertex): first-glossy minus direct, with only the indirect
                light's noise.
``full``        path tracing with the full BRDF at every vertex.

Estimator. At every shading vertex, next-event estimation samples each light once
(point, spot and directional lights deterministically; a uniform point on each quad; a
direction from each environment map's luminance distribution) and the BRDF is sampled
once to continue the path. Quad lights tied to an emitting object and environment maps
can be reached by both strategies and are combined with the power heuristic; delta
lights by light sampling only. Russian roulette (survival probability
min(max throughput, 0.95)) starts after ``rr_depth`` vertices. ``emission`` adds
test-only emitting objects reached by BRDF sampling alone (weight 1).

Shading frame (``pipeline.device.raytrace.surface_at``, as in the G-buffer, here in float64): the
normal is the barycentric blend of vertex normals turned to face the incoming ray, the
tangent follows +u of the mesh's uv; a material's bump map turns that frame and its
blend mixes two BRDFs, (1 − t) f_a + t f_b, sampled as the mixture (material b with
probability t; pipeline/render/surface_detail.py). Shadow rays leave from the geometric
point along the face normal whatever the bump (the physically bumped reference that
method triple's approximation is measured against). A direction
on the shading side of the normal but behind the triangle's plane carries nothing. Ray
origins are offset by ``1e-4`` × the scene diagonal along the triangle's normal.

Progressive rendering. Passes of ``spp_per_pass`` paths per pixel accumulate per-pixel
sums and sums of squares; the variance of each pixel's mean is s²/n. The estimated
relative RMSE is √(Σ s²/n) / √(Σ mean²) over the channels of the *surface* pixels;
rendering stops once it is ≤ ``tolerance`` (after ``min_spp``) or at ``max_spp``. Pass p
draws its random numbers from ``numpy.random.default_rng([seed, p])``: a given seed gives
the same image bit for bit.

Which pixels the estimate covers. A pixel is left out (an *emitter pixel*) when any of
its camera paths so far took radiance straight from a light at the first ray: its first
hit is an emitting surface seen from its emitting side (a quad light's ``object``, or a
test ``emission`` object) whose emission the transport counts, or the ray escapes to an
environment map the transport shows. Those pixels hold the light's own radiance, exact
or nearly so, and it can dwarf the lit surfaces (the Cornell luminaire: 18 against
≈ 0.3 W/(m² sr)): over the whole image, their Σ mean² fills the norm. On
scenes/cornell_box_lambert.yaml at 128² (box filter) the whole-image estimate stopped
at 832 spp saying 1.0 % while the surfaces were 2.1 % off a 3864-spp render; at 20²
with pixel-centre paths it says 0.4 % where the surfaces are 5 % off. The environment
background counts as an emitter pixel for the same reason, although it is no surface: a
map seen directly is exact with the ``center`` filter (with ``box``, its only noise is
the map's variation across the pixel, not light transport) and a bright map would
likewise hide the error of the objects in front of it. An emitter seen from behind, or
one the transport leaves out (``env-direct`` ignores quad lights, ``first-glossy-indirect`` all
light seen directly), is an ordinary surface pixel. If every pixel is an emitter pixel,
the estimate covers them all. ``history`` also keeps the whole-image estimate, to show
what the two would have decided.

Pixel filter: ``center`` traces every path through the pixel centre, like the methods'
one view sample per pixel (so edges match them); ``box`` jitters uniformly over the
pixel (Mitsuba's box filter).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from pipeline.device.raytrace import RAY_EPSILON, Mesh, RayTracer, surface_at
from pipeline.math import brdf_sampling
from pipeline.math.brdf import BrdfParams, evaluate, scene_brdfs
from pipeline.math.camera import pixel_directions
from pipeline.math.envmap import EnvironmentMap
from pipeline.math.lights import TYPE_CODES, LightRow, pack_lights, quad_normal, smoothstep
from pipeline.render.surface_detail import SceneDetail
from pipeline.scene.model import Scene

TRANSPORTS = ("direct", "env-direct", "first-glossy", "first-glossy-indirect", "full")
# the part of the BRDF at the first surface a camera path meets (later vertices: as the
# transport has them): all of it, its glossy part only (the diffuse albedo set to 0), or
# its diffuse part only (a Lambertian BRDF of the material's albedo). A lobe's image
# holds reflected light only (no emitter or environment seen directly): glossy +
# diffuse = all less that, per path (method sg's glossy and diffuse images, apart)
LOBES = ("all", "glossy", "diffuse")
PIXEL_FILTERS = ("center", "box")
PATHS_PER_PASS = 1 << 17


@dataclass(frozen=True)
class ReferenceSettings:
    """How to render: ``transport`` (one of :data:`TRANSPORTS`), stop at estimated
    relative RMSE ``tolerance`` (a fraction, over the surface pixels: see the module
    docstring) or ``max_spp`` paths per pixel, never before ``min_spp``; ``max_depth``
    bounds the shading vertices per path (-1: none); ``lobe`` (one of :data:`LOBES`): the
    part of the BRDF at the first surface."""

    transport: str = "full"
    tolerance: float = 0.01
    max_spp: int = 4096
    min_spp: int = 16
    seed: int = 0
    max_depth: int = -1
    rr_depth: int = 5
    pixel_filter: str = "center"
    spp_per_pass: int | None = None  # default: about PATHS_PER_PASS paths per pass
    lobe: str = "all"

    def __post_init__(self) -> None:
        if self.transport not in TRANSPORTS:
            raise ValueError(f"unknown transport {self.transport!r} "
                             f"(transports: {', '.join(TRANSPORTS)})")
        if self.lobe not in LOBES:
            raise ValueError(f"unknown lobe {self.lobe!r} (lobes: {', '.join(LOBES)})")
        if self.pixel_filter not in PIXEL_FILTERS:
            raise ValueError(f"unknown pixel filter {self.pixel_filter!r}")
        if not (self.tolerance >= 0 and self.max_spp >= 1 and self.min_spp >= 1):
            raise ValueError("tolerance must be >= 0 and max_spp, min_spp >= 1")


@dataclass
class ReferenceImage:
    """A rendered reference: ``mean`` (H, W, 3) radiance in W/(m² sr), ``variance``
    (H, W, 3) the estimated variance of each pixel's mean, ``spp`` paths per pixel,
    ``estimate`` the estimated relative RMSE (a fraction, 0.01 = 1 %) over the surface
    pixels (see the module docstring), ``seconds`` of rendering, ``rays`` traced,
    ``history`` [(spp, estimate, seconds, whole-image estimate)] after every pass, and
    ``emitter_pixels`` (H, W) bool, True where a camera path saw a light directly: the
    pixels the estimate leaves out (None for an image read back from a cache, which
    does not store it; older caches' history rows have three entries)."""

    mean: np.ndarray
    variance: np.ndarray
    spp: int
    estimate: float
    seconds: float
    rays: int
    history: list[tuple[int, float, float, float]] = field(default_factory=list)
    emitter_pixels: np.ndarray | None = None


def relative_rmse_estimate(mean: np.ndarray, variance: np.ndarray,
                           mask: np.ndarray | None = None) -> float:
    """√(Σ variance) / √(Σ mean²) over the pixels in ``mask`` (None or all False:
    every pixel): the expected relative RMSE of ``mean`` there, a fraction. ``mean``
    and ``variance`` are (..., 3), ``mask`` has their leading shape."""
    if mask is not None and np.any(mask):
        mean, variance = mean[mask], variance[mask]
    norm = float(np.sum(np.square(mean, dtype=np.float64)))
    return math.sqrt(float(np.sum(variance, dtype=np.float64)) / norm) if norm > 0 else math.inf


class TransportScene:
    """Everything a path needs: Embree scene, per-face shading data, BRDFs, lights.

    ``geometry`` holds the geometry artifact's arrays (vertices, normals, uv, faces,
    face_object, object_material) and its ``object_names`` and ``material_names``;
    ``emission`` maps object names to test-only emitted radiance (RGB)."""

    def __init__(self, scene: Scene, geometry: dict, emission: dict | None = None) -> None:
        v = np.asarray(geometry["vertices"], np.float64)
        faces = np.asarray(geometry["faces"], np.int64)
        # shading attributes at hits, the normal blended in float64
        self.mesh = Mesh(v, np.asarray(geometry["normals"], np.float64),
                         np.asarray(geometry["uv"], np.float64), faces,
                         np.asarray(geometry["face_object"], np.int64),
                         np.asarray(geometry["object_material"], np.int64))
        self.face_object = self.mesh.face_object
        object_names = list(geometry["object_names"])
        self.materials = scene_brdfs(scene, list(geometry["material_names"]))
        self.detail = SceneDetail(scene, list(geometry["material_names"]))
        self.lambert = [BrdfParams("lambert", p.albedo) for p in self.materials]
        self.glossy = [replace(p, albedo=(0.0, 0.0, 0.0)) for p in self.materials]
        self.tracer = RayTracer(v, faces)
        self.epsilon = RAY_EPSILON * float(np.linalg.norm(v.max(0) - v.min(0)))
        self.camera = scene.camera
        lights = [(light.type, light.params) for light in scene.lights
                  if light.type != "environment"]
        self.lights = pack_lights(lights, {n: i for i, n in enumerate(object_names)}
                                  ).astype(np.float64)
        from pipeline.images import read_environment

        self.environments = [EnvironmentMap(read_environment(env.file), env.rotation,
                                            env.scale, env.axis)
                             for env in (light.environment() for light in scene.lights
                                         if light.type == "environment")]
        self.emission = np.zeros((len(object_names), 3))
        self.emitter_light = np.full(len(object_names), -1)
        for i, row in enumerate(self.lights):
            if int(row[LightRow.TYPE]) == TYPE_CODES["quad"] and row[LightRow.OBJECT] >= 0:
                self.emitter_light[int(row[LightRow.OBJECT])] = i
        for name, radiance in (emission or {}).items():
            self.emission[object_names.index(name)] = radiance


@dataclass
class _Vertex:
    """Shading vertices of the live paths: points, frames, materials, outgoing ``wo``;
    where materials blend, ``material_b`` and its weight ``blend`` (None: no blends)."""

    x: np.ndarray
    n: np.ndarray
    t: np.ndarray
    ng: np.ndarray
    wo: np.ndarray
    material: np.ndarray
    prim: np.ndarray | None = None
    material_b: np.ndarray | None = None
    blend: np.ndarray | None = None

    def local(self, w: np.ndarray) -> np.ndarray:
        b = np.cross(self.n, self.t)
        return np.stack([np.sum(w * self.t, -1), np.sum(w * b, -1), np.sum(w * self.n, -1)], -1)

    def world(self, w: np.ndarray) -> np.ndarray:
        b = np.cross(self.n, self.t)
        return w[:, :1] * self.t + w[:, 1:2] * b + w[:, 2:] * self.n


def _per_material(material: np.ndarray, table: list[BrdfParams], fn, shape) -> np.ndarray:
    out = np.zeros(shape)
    for index in np.unique(material):
        sel = material == index
        out[sel] = fn(sel, table[index])
    return out


def _blended(vtx: _Vertex, table: list[BrdfParams], fn, shape) -> np.ndarray:
    """``fn`` per material, (1 − t) · of material a + t · of material b where blended."""
    out = _per_material(vtx.material, table, fn, shape)
    if vtx.blend is None:
        return out
    t = vtx.blend.reshape((-1,) + (1,) * (len(shape) - 1))
    return (1 - t) * out + t * _per_material(vtx.material_b, table, fn, shape)


def _brdf(vtx: _Vertex, wi_local: np.ndarray, table: list[BrdfParams]) -> np.ndarray:
    wo = vtx.local(vtx.wo)
    return _blended(vtx, table, lambda s, p: evaluate(wi_local[s], wo[s], p), (len(wo), 3))


def _brdf_pdf(vtx: _Vertex, wi_local: np.ndarray, table: list[BrdfParams]) -> np.ndarray:
    wo = vtx.local(vtx.wo)
    return _blended(vtx, table, lambda s, p: brdf_sampling.pdf(wi_local[s], wo[s], p),
                    (len(wo),))


def _power(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Power-heuristic weight of the strategy with density ``a`` against ``b``."""
    ratio = np.divide(b, a, out=np.zeros(np.shape(a)), where=a > 0)
    return np.where(a > 0, 1.0 / (1.0 + ratio * ratio), 0.0)


class PathTracer:
    """Traces paths of one transport through a :class:`TransportScene`."""

    def __init__(self, ts: TransportScene, settings: ReferenceSettings) -> None:
        self.ts = ts
        self.s = settings
        self.use_local = settings.transport != "env-direct"
        self.one_vertex = settings.transport in ("direct", "env-direct")
        self.lambert_bounces = settings.transport in ("first-glossy", "first-glossy-indirect")
        # vertices (0: seen from the camera) whose light arrives without a bounce
        self.skip_direct = settings.transport == "first-glossy-indirect"
        self.first_table = {"all": ts.materials, "glossy": ts.glossy,
                            "diffuse": ts.lambert}[settings.lobe]
        # one lobe's image holds reflected light only: not what the camera sees directly
        self.lobe_only = settings.lobe != "all"
        self.rays = 0

    # ------------------------------------------------------------------------ lights

    def _shadow(self, vtx: _Vertex, wi: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """1.0 where the segment from each vertex along ``wi`` over ``dist`` (≥ 1e30:
        unbounded) is free. The ray leaves from the offset origin towards the same end
        point and stops 1e-4 of its length short of it, so that an emitter's own
        surface does not shadow it."""
        side = np.sign(np.sum(vtx.ng * wi, -1))[:, None]
        origin = vtx.x + self.ts.epsilon * side * vtx.ng
        finite = dist < 1e30
        direction = np.where(finite[:, None], vtx.x + wi * np.where(finite, dist, 0)[:, None]
                             - origin, wi)
        length = np.linalg.norm(direction, axis=-1)
        direction /= np.maximum(length, 1e-300)[:, None]
        self.rays += len(wi)
        blocked = self.ts.tracer.occluded(origin, direction,
                                          np.where(finite, length * (1 - 1e-4), 1e30))
        return (~blocked).astype(np.float64)

    def _connect(self, vtx: _Vertex, wi: np.ndarray, table) -> tuple[np.ndarray, np.ndarray]:
        """BRDF × cos θi (N, 3) towards world ``wi`` and the mask of usable directions."""
        li = vtx.local(wi)
        ok = (li[:, 2] > 0) & (np.sum(vtx.ng * wi, -1) > 0)
        return _brdf(vtx, li, table) * np.maximum(li[:, 2], 0)[:, None] * ok[:, None], ok

    def next_event(self, vtx: _Vertex, table, rng: np.random.Generator) -> np.ndarray:
        """Light reaching each vertex from every light, reflected towards ``wo`` (N, 3)."""
        f = LightRow
        n = len(vtx.x)
        out = np.zeros((n, 3))
        for row in self.ts.lights if self.use_local else ():
            kind = int(row[f.TYPE])
            if kind == TYPE_CODES["directional"]:
                wi = np.broadcast_to(-row[f.DIRECTION], (n, 3))
                dist, scale = np.full(n, 1e30), np.ones(n)
            else:
                q = row[f.POSITION]
                if kind == TYPE_CODES["quad"]:
                    u = rng.random((n, 2))
                    q = row[f.CORNER] + u[:, :1] * row[f.EDGE_U] + u[:, 1:] * row[f.EDGE_V]
                d = q - vtx.x
                dist = np.linalg.norm(d, axis=-1)
                wi = d / np.maximum(dist, 1e-300)[:, None]
                scale = 1.0 / np.maximum(dist * dist, 1e-300)
                if kind == TYPE_CODES["spot"]:
                    scale = scale * smoothstep(row[f.COS_OUTER], row[f.COS_INNER],
                                               -(wi @ row[f.DIRECTION]))
            fcos, ok = self._connect(vtx, wi, table)
            if kind == TYPE_CODES["quad"]:
                nq = quad_normal(row)
                area = np.linalg.norm(nq)
                cos_l = -(wi @ (nq / area))
                ok &= cos_l > 0
                light_pdf = np.divide(dist * dist, cos_l * area, out=np.zeros(n), where=ok)
                weight = np.ones(n)
                if row[f.OBJECT] >= 0:  # reachable by BRDF sampling too
                    weight = _power(light_pdf, _brdf_pdf(vtx, vtx.local(wi), table))
                scale = weight / np.maximum(light_pdf, 1e-300)
            vis = np.zeros(n)
            if ok.any():
                vis[ok] = self._shadow(_subset(vtx, ok), wi[ok], dist[ok])
            out += fcos * (row[f.RGB] * (scale * vis)[:, None])
        for env in self.ts.environments:
            wi, env_pdf = env.sample(rng.random((n, 3)))
            fcos, ok = self._connect(vtx, wi, table)
            weight = _power(env_pdf, _brdf_pdf(vtx, vtx.local(wi), table))
            vis = np.zeros(n)
            if ok.any():
                vis[ok] = self._shadow(_subset(vtx, ok), wi[ok], np.full(int(ok.sum()), 1e30))
            out += fcos * env.radiance(wi) * (weight * vis / np.maximum(env_pdf, 1e-300))[:, None]
        return out

    # ------------------------------------------------------------------------- paths

    def camera_paths(self, pixel: np.ndarray, rng: np.random.Generator,
                     sees_light: np.ndarray | None = None) -> np.ndarray:
        """One path sample per entry of ``pixel`` (flat pixel ids): radiance (N, 3) in
        W/(m² sr). ``sees_light`` (N,) bool, if given, is set True where the camera ray
        itself took emitted or environment radiance (the module docstring's emitter
        pixels)."""
        cam = self.ts.camera
        row, col = np.divmod(pixel, cam.width)
        jitter = rng.random((len(pixel), 2)) if self.s.pixel_filter == "box" \
            else np.full((len(pixel), 2), 0.5)
        d = pixel_directions(cam.position, cam.look_at, cam.up, cam.fov, cam.width,
                             cam.height, col + jitter[:, 0], row + jitter[:, 1])
        o = np.broadcast_to(np.asarray(cam.position, float), d.shape).copy()
        radiance = np.zeros((len(pixel), 3))
        throughput = np.ones((len(pixel), 3))
        alive = np.arange(len(pixel))
        brdf_pdf = np.zeros(len(pixel))  # density of the direction that led here (0: camera)
        depth = 0
        while len(alive):
            hits = self.ts.tracer.intersect(o, d)
            self.rays += len(o)
            miss = hits.prim < 0
            shown = self._add_environment(radiance, alive[miss], throughput[miss], d[miss],
                                          brdf_pdf[miss], depth)
            if sees_light is not None and depth == 0 and shown:
                sees_light[alive[miss]] = True
            hit = ~miss
            alive, o, d, throughput, brdf_pdf = (alive[hit], o[hit], d[hit], throughput[hit],
                                                 brdf_pdf[hit])
            if not len(alive):
                break
            vtx = self._vertex(o, d, hits, hit)
            emitted = self._add_emission(radiance, alive, throughput, vtx, hits.t[hit],
                                         brdf_pdf, depth)
            if sees_light is not None and depth == 0:
                sees_light[alive[emitted]] = True
            if self.one_vertex and depth == 1 or depth == self.s.max_depth:
                break
            table = self.first_table if depth == 0 else \
                self.ts.lambert if self.lambert_bounces else self.ts.materials
            if not (self.skip_direct and depth == 0):
                radiance[alive] += throughput * self.next_event(vtx, table, rng)
            wi_local, brdf_pdf, weight = self._sample_brdf(vtx, table, rng)
            throughput = throughput * weight
            if depth + 1 >= self.s.rr_depth:
                survive = np.minimum(throughput.max(axis=1), 0.95)
                keep = rng.random(len(alive)) < survive
                throughput = throughput / np.maximum(survive, 1e-300)[:, None]
            else:
                keep = np.ones(len(alive), bool)
            keep &= throughput.max(axis=1) > 0
            d = vtx.world(wi_local)
            side = np.sign(np.sum(vtx.ng * d, -1))[:, None]
            o = vtx.x + self.ts.epsilon * side * vtx.ng
            alive, o, d, throughput, brdf_pdf = (alive[keep], o[keep], d[keep],
                                                 throughput[keep], brdf_pdf[keep])
            depth += 1
        return radiance

    def _vertex(self, o, d, hits, hit) -> _Vertex:
        s = surface_at(self.ts.mesh, hits.select(hit), o, d)
        if self.ts.detail.empty:
            return _Vertex(s.position, s.normal, s.tangent, s.geometric_normal, -d,
                           s.material_id, s.face)
        detail = self.ts.detail.at(s)
        return _Vertex(s.position, detail.normal, detail.tangent, s.geometric_normal, -d,
                       detail.material_a, s.face, detail.material_b, detail.blend)

    def _add_environment(self, radiance, index, throughput, d, brdf_pdf, depth) -> bool:
        """Add the environment's radiance to escaped paths; whether this transport
        counts it at this depth."""
        if not self.ts.environments or (self.one_vertex and depth > 1) \
                or (self.skip_direct and depth <= 1) or (self.lobe_only and depth == 0):
            return False
        for env in self.ts.environments:
            weight = np.ones(len(d)) if depth == 0 else _power(brdf_pdf, env.pdf(d))
            radiance[index] += throughput * env.radiance(d) * weight[:, None]
        return True

    def _add_emission(self, radiance, index, throughput, vtx, dist, brdf_pdf,
                      depth) -> np.ndarray:
        """Add emitted radiance where the paths hit an emitter; (N,) bool, True where
        an emitter sends radiance back along the path (before MIS weights)."""
        emitted = np.zeros(len(index), bool)
        if self.skip_direct and depth <= 1 or self.lobe_only and depth == 0:
            return emitted
        ts = self.ts
        obj = ts.face_object[vtx.prim]
        test_emission = ts.emission[obj]
        emitted |= np.any(test_emission > 0, axis=-1)
        if self.use_local:
            light = ts.emitter_light[obj]
            for li in np.unique(light[light >= 0]):
                row = ts.lights[li]
                nq = quad_normal(row)
                area = np.linalg.norm(nq)
                cos_l = vtx.wo @ (nq / area)
                sel = (light == li) & (cos_l > 0)
                emitted |= sel & bool(np.any(row[10:13] > 0))
                if depth == 0:
                    weight = np.ones(int(sel.sum()))
                else:
                    d = dist[sel].astype(np.float64)
                    light_pdf = d * d / (cos_l[sel] * area)
                    weight = _power(brdf_pdf[sel], light_pdf)
                radiance[index[sel]] += throughput[sel] * row[LightRow.RGB] * weight[:, None]
        radiance[index] += throughput * test_emission
        return emitted

    def _sample_brdf(self, vtx: _Vertex, table, rng):
        """Sampled local directions, their densities and BRDF × cos / density (N, 3);
        a blend samples material b with probability t (the mixture's density)."""
        n = len(vtx.x)
        u = rng.random((n, 3))
        wo = vtx.local(vtx.wo)
        wi = np.zeros((n, 3))
        pdf = np.zeros(n)
        chosen = vtx.material
        if vtx.blend is not None:
            chosen = np.where(rng.random(n) < vtx.blend, vtx.material_b, vtx.material)
        for index in np.unique(chosen):
            sel = chosen == index
            wi[sel] = brdf_sampling.sample(wo[sel], u[sel], table[index])
            pdf[sel] = brdf_sampling.pdf(wi[sel], wo[sel], table[index])
        if vtx.blend is not None:
            pdf = _brdf_pdf(vtx, wi, table)
        ok = (wi[:, 2] > 0) & (np.sum(vtx.world(wi) * vtx.ng, -1) > 0) & (pdf > 0)
        f = _brdf(vtx, wi, table)
        weight = np.where(ok[:, None], f * wi[:, 2:3] / np.where(ok, pdf, 1.0)[:, None], 0.0)
        return wi, pdf, weight


def _subset(vtx: _Vertex, mask: np.ndarray) -> _Vertex:
    blended = vtx.blend is not None
    return _Vertex(vtx.x[mask], vtx.n[mask], vtx.t[mask], vtx.ng[mask], vtx.wo[mask],
                   vtx.material[mask], None, vtx.material_b[mask] if blended else None,
                   vtx.blend[mask] if blended else None)


def render(scene: Scene, geometry: dict, settings: ReferenceSettings,
           emission: dict | None = None, progress: bool = False) -> ReferenceImage:
    """Render the scene's camera view progressively (see the module docstring)."""
    start = time.perf_counter()
    ts = TransportScene(scene, geometry, emission)
    tracer = PathTracer(ts, settings)
    cam = scene.camera
    npix = cam.width * cam.height
    per_pass = settings.spp_per_pass or max(1, PATHS_PER_PASS // npix)
    total = np.zeros((npix, 3))
    total_sq = np.zeros((npix, 3))
    emitter = np.zeros(npix, bool)  # a path of the pixel saw a light directly
    spp, estimate, history = 0, math.inf, []
    bar = _progress_bar(settings, progress)
    pass_index = 0
    while spp < settings.max_spp:
        count = min(per_pass, settings.max_spp - spp)
        rng = np.random.default_rng([settings.seed, pass_index])
        pixel = np.tile(np.arange(npix), count)
        sees_light = np.zeros(len(pixel), bool)
        samples = tracer.camera_paths(pixel, rng, sees_light).reshape(count, npix, 3)
        emitter |= sees_light.reshape(count, npix).any(axis=0)
        total += samples.sum(axis=0)
        total_sq += np.square(samples).sum(axis=0)
        spp += count
        pass_index += 1
        mean, variance = _moments(total, total_sq, spp)
        estimate = relative_rmse_estimate(mean, variance, ~emitter)
        history.append((spp, estimate, time.perf_counter() - start,
                        relative_rmse_estimate(mean, variance)))
        if bar is not None:
            bar.update(count)
            bar.set_postfix_str(f"rel. RMSE ≈ {estimate:.4f}")
        if spp >= settings.min_spp and estimate <= settings.tolerance:
            break
    if bar is not None:
        bar.close()
    mean, variance = _moments(total, total_sq, spp)
    shape = (cam.height, cam.width, 3)
    return ReferenceImage(mean.reshape(shape).astype(np.float32),
                          variance.reshape(shape).astype(np.float32), spp, estimate,
                          time.perf_counter() - start, tracer.rays, history,
                          emitter.reshape(shape[:2]))


def _moments(total: np.ndarray, total_sq: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel means and variances of the means from sums over ``n`` samples."""
    mean = total / n
    if n < 2:
        return mean, np.full_like(mean, np.inf)
    sample_var = np.maximum(total_sq / n - mean * mean, 0.0) * n / (n - 1)
    return mean, sample_var / n


def _progress_bar(settings: ReferenceSettings, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=settings.max_spp, unit="spp", desc=f"reference {settings.transport}",
                leave=False)

