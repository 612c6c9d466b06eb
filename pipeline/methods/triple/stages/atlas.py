"""Stage ``triple.atlas``: a UV atlas per object (xatlas) and the surface under every texel.

Per object (one chunk each, keyed on that object's geometry chunk and the camera):

**Texture size.** The object's size on screen is P, the number of pixels of the scene
camera whose centre ray hits the object drawn alone (others do not hide it, so moving
them changes nothing here); its surface area is A (scene units²). Its texel density is

    ρ = texels_per_pixel · √(P / A)        texels per scene unit,

so the whole surface gets about texels_per_pixel² texels per pixel it covers on screen
(a closed object shows about half of its surface: there a texel is ≈ 1/√2 pixel wide at
texels_per_pixel = 1). The texture's side is then about ρ √(A / 0.7) (xatlas fills
≈ 70 % of a large texture); that target side is clamped to [texture_min, texture_max],
ρ set from it, and the charts packed at ρ; where padding makes the packed side miss the
target by more than 20 % (small textures: each chart adds its padding), ρ is scaled by
target / side and the charts packed again, at most three times. A small or far object
gets a small texture, an object off screen one of about texture_min.

**Atlas.** xatlas's charts (its default chart options) packed with ``padding`` = 2
texels between charts and bilinear mode, so the footprints of two charts (the texels a
bilinear fetch inside a chart reads: pipeline/methods/triple/texels.py) never share a texel.
Every texel in a footprint is covered or dilated (:func:`pipeline.methods.triple.texels.rasterize`)
and gets a surface point on the mesh, so bilinear fetches never read an empty texel.

**Per texel** (covered and dilated; zeros where empty): the surface point, shading
normal and tangent from :func:`pipeline.device.raytrace.surface_at` exactly as the G-buffer
has them (the normal the barycentric blend of vertex normals, normalised; the tangent
along +u of the mesh's own uv where it has one, else a frame from the normal), except
that no ray turns the normal: it is the mesh's outward one (the side of the face
normal, counter-clockwise winding). Schema ``triple_atlas``.
"""

from __future__ import annotations

import numpy as np

from pipeline.device.raytrace import Hits, Mesh, RayTracer, surface_at
from pipeline.engine.chunkwrite import segment_name
from pipeline.engine.stage import AssembleContext, Chunk, ChunkContext, Layout, Output
from pipeline.errors import PrtError
from pipeline.math.camera import camera_rays
from pipeline.methods.triple import texels

PADDING = 2               # texels between charts: footprints reach < 1 texel past a chart
PACKING_EFFICIENCY = 0.7  # charts' share of the packed texture, to predict its side
SIDE_TOLERANCE = 0.2      # a packed side this far from its target is packed again,
REPACKS = 3               # at most this many times

# The last atlas made in this process, kept alive until the next one is made (or the
# process ends). Freeing an xatlas Atlas (xatlas::Destroy) stops its task scheduler's
# worker threads, and it wakes them without taking their mutex (jpcy/xatlas,
# source/xatlas/xatlas.cpp, TaskScheduler::~TaskScheduler and workerThread): a worker
# that is still on its way back to sleep after generate()'s last task misses the wake-up,
# and join() waits for it forever. Seen once, in a clean-clone CI run: a pool worker in
# ~TaskScheduler's join for ten minutes at no CPU (py-spy --native), the suite stalled.
# Freed one atlas later, its workers have long been asleep and the wake-up reaches them.
_held_atlas: list = [None]


def object_piece(artifact, name: str, obj: str) -> np.ndarray:
    """The piece of segmented array ``name`` that the chunk of object ``obj`` wrote."""
    return np.asarray(artifact.group[name][segment_name(obj)][...])


def screen_pixels(vertices: np.ndarray, faces: np.ndarray, camera: dict) -> int:
    """Pixels of ``camera`` whose centre ray hits the mesh (alone)."""
    origins, dirs = camera_rays(camera["position"], camera["look_at"], camera["up"],
                                camera["fov"], camera["width"], camera["height"])
    return int(np.count_nonzero(RayTracer(vertices, faces).intersect(origins, dirs).prim >= 0))


def _pack(vertices: np.ndarray, faces: np.ndarray, density: float
          ) -> tuple[np.ndarray, int, int]:
    """xatlas at ``density`` texels per unit: per face its three corners' uv in texel
    units (F, 3, 2) (faces in input order), and the texture's height and width."""
    import xatlas

    # xatlas's tolerances are absolute: the mesh goes in centred and scaled to a unit
    # extent (an object 1e-6 units wide had every face dropped as degenerate), the
    # density scaled to match; the texel layout is the same
    v = np.asarray(vertices, np.float64)
    extent = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    extent = extent if extent > 0 else 1.0
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray((v - v.mean(axis=0)) / extent, np.float32),
                   np.ascontiguousarray(faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.texels_per_unit, pack.padding, pack.bilinear = float(density) * extent, PADDING, True
    atlas.generate(xatlas.ChartOptions(), pack)
    _held_atlas[0] = atlas  # frees the previous one, long idle (see _held_atlas)
    mapping, indices, uv = atlas[0]
    if atlas.atlas_count != 1 or not np.array_equal(mapping[indices], faces):
        raise PrtError(None, f"xatlas could not lay out the mesh's {len(faces)} faces "
                       f"in one atlas ({atlas.atlas_count} atlases; are they degenerate, "
                       "or collapsed by float32 far from the origin?)")
    width, height = int(atlas.width), int(atlas.height)
    return uv[indices].astype(np.float64) * [width, height], height, width


def packed_atlas(vertices: np.ndarray, faces: np.ndarray, pixels: int, params: dict
                 ) -> tuple[np.ndarray, int, int]:
    """The atlas of one object at the density of the module docstring's rule."""
    lo, hi = int(params["triple.texture_min"]), int(params["triple.texture_max"])
    v = vertices.astype(np.float64)
    area = 0.5 * float(np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]],
                                               v[faces[:, 2]] - v[faces[:, 0]]), axis=1).sum())
    unit_side = np.sqrt(area / PACKING_EFFICIENCY)  # predicted side at density 1
    wanted = float(params["triple.texels_per_pixel"]) * np.sqrt(pixels / area) * unit_side
    target = float(np.clip(wanted, lo, hi))
    density = target / unit_side
    for _ in range(1 + REPACKS):
        face_uv, height, width = _pack(vertices, faces, density)
        side = max(height, width)
        if abs(side - target) <= SIDE_TOLERANCE * target:
            break
        density *= target / side
    return face_uv, height, width


def run_chunk(ctx: ChunkContext) -> dict[str, np.ndarray]:
    obj = ctx.chunk.object
    geometry = ctx.inputs["geometry"]
    arrays = {n: object_piece(geometry, n, obj) for n in ("vertices", "normals", "uv", "faces")}
    vertices, faces = arrays["vertices"], arrays["faces"]
    pixels = screen_pixels(vertices, faces, ctx.scene["camera"])
    try:
        face_uv, height, width = packed_atlas(vertices, faces, pixels, ctx.params)
    except PrtError as exc:
        raise PrtError(None, f"objects.{obj}: {exc.problem}") from None
    state, face, bary = texels.rasterize(face_uv, height, width)

    filled = face >= 0
    mesh = Mesh(vertices, arrays["normals"], arrays["uv"], faces,
                np.zeros(len(faces), np.int32), np.zeros(1, np.int32))
    position = np.einsum("nk,nkc->nc", bary[filled], vertices[faces[face[filled]]]
                         .astype(np.float64))
    hits = Hits(np.zeros(int(filled.sum()), np.float32), face[filled],
                bary[filled, 1], bary[filled, 2])
    surface = surface_at(mesh, hits, position, -mesh.face_normal[face[filled]])

    def texel_array(values: np.ndarray) -> np.ndarray:
        out = np.zeros((len(face), values.shape[1]), np.float32)
        out[filled] = values
        return out

    ctx.meta.update({"texture_size": [height, width], "screen_pixels": pixels,
                     "faces": len(faces), **{f"{name}_texels": int(np.sum(state == value))
                                             for name, value in texels.TEXEL_STATES.items()}})
    return {
        "face_uv": face_uv.astype(np.float32),
        "texel_state": state,
        "texel_face": face,
        "texel_position": texel_array(surface.position),
        "texel_normal": texel_array(surface.normal),
        "texel_tangent": texel_array(surface.tangent),
    }


def layout(ctx: AssembleContext) -> Layout:
    return Layout(sizes={"texel_chunk": 1 << 16, "face_chunk": 1 << 16})


def finalize(ctx: AssembleContext, metas: list[tuple[Chunk, dict]]) -> Output:
    """Texture sizes and where each object's texels start in the flat texel arrays."""
    sizes = {chunk.object: meta["texture_size"] for chunk, meta in metas}
    counts = [h * w for h, w in sizes.values()]
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    return Output(
        attrs={"texture_sizes": sizes,
               "screen_pixels": {c.object: m["screen_pixels"] for c, m in metas},
               "texel_counts": {c.object: {s: m[f"{s}_texels"] for s in texels.TEXEL_STATES}
                                for c, m in metas},
               "texel_states": dict(texels.TEXEL_STATES),
               "uv_units": "texels",
               "texels_per_pixel": float(ctx.params["triple.texels_per_pixel"]),
               "texture_min": int(ctx.params["triple.texture_min"]),
               "texture_max": int(ctx.params["triple.texture_max"]),
               "padding": PADDING},
        arrays={"texture_offsets": offsets})
