"""Surface detail at hits: spatially varying BRDFs (a blend of two materials by a
texture) and bump maps (paper 004 §4.2), for every renderer that shades hits.

Per hit of a :class:`~pipeline.device.raytrace.Surface` (N hits), :meth:`SceneDetail.at`
returns a :class:`SurfaceDetail`:

* ``material_a`` the hit's own material, ``material_b`` the material it blends with
  (= ``material_a`` without a blend) and ``blend`` t ∈ [0, 1], the texture's value: the
  BRDF is f = (1 − t) f_a + t f_b;
* ``normal``, ``tangent`` the shading frame: the surface's interpolated normal turned
  by the material's bump map (pipeline/math/textures.py ``bumped_normal``) and its
  tangent made orthogonal to that normal again (Gram–Schmidt). Without a bump they are
  the surface's own.

Texture coordinates (scene ``TextureMap``): ``projection: uv`` reads the mesh's uv
(times ``scale``), whose surface gradients ∇u, ∇v come per face from the uv of its
corners (``uv_gradients``); ``xy``/``xz``/``yz`` read the hit's world coordinates on
those two axes × ``scale`` (∇u, ∇v = ``scale`` × the axes). The bump's height is
measured along the *outward* normal (the face's winding), whichever side the ray sees.

How renderers use it: the BRDF and the cosine use the bumped frame; shadow rays and
visibility stay with the geometric surface (its position and face normal; method
triple's visibility textures are in the unbumped texel frame, the paper's
approximation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.device.raytrace import Mesh, Surface
from pipeline.images import read_texture
from pipeline.math.frames import orthonormalize
from pipeline.math.textures import bumped_normal, sample, uv_gradients
from pipeline.scene.model import Scene, TextureMap

AXES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


@dataclass
class SurfaceDetail:
    """Per hit (N of them), world frame: unit shading ``normal`` and ``tangent``
    (N, 3) float64, ``material_a``, ``material_b`` (N,) int64 and ``blend`` (N,)
    float64 (the weight of ``material_b``)."""

    normal: np.ndarray
    tangent: np.ndarray
    material_a: np.ndarray
    material_b: np.ndarray
    blend: np.ndarray


@dataclass
class _Texture:
    """A loaded texture and how it maps onto surfaces."""

    values: np.ndarray
    mapping: TextureMap

    def at(self, gradients: tuple[np.ndarray, np.ndarray] | None, surface: Surface,
           which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values (K,) and world gradients (K, 3) (per scene unit) at the hits
        ``which`` (K,) of ``surface``; ``gradients`` the mesh's per-face ∇u, ∇v."""
        m = self.mapping
        if m.projection == "uv":
            uv = surface.uv[which] * m.scale
            face = surface.face[which]
            grad_u, grad_v = (g[face] * m.scale for g in gradients)
        else:
            a, b = AXES[m.projection]
            uv = surface.position[which][:, [a, b]] * m.scale
            grad_u = np.zeros((len(uv), 3))
            grad_v = np.zeros((len(uv), 3))
            grad_u[:, a] = m.scale
            grad_v[:, b] = m.scale
        value, d = sample(self.values, uv, m.wrap)
        return value, d[:, :1] * grad_u + d[:, 1:] * grad_v


class SceneDetail:
    """The blends and bump maps of a scene's materials, textures loaded once.
    ``material_names`` orders the materials as the hits' ``material_id`` counts them
    (the geometry artifact's ``material_names``)."""

    def __init__(self, scene: Scene, material_names: list[str]) -> None:
        self.names = list(material_names)
        self.blend: dict[int, tuple[int, _Texture]] = {}
        self.bump: dict[int, tuple[float, _Texture]] = {}
        self._gradients: tuple[Mesh, tuple[np.ndarray, np.ndarray]] | None = None
        for m, name in enumerate(self.names):
            material = scene.materials[name]
            if material.blend is not None:
                texture = _Texture(read_texture(material.blend.texture.file),
                                   material.blend.texture)
                self.blend[m] = (self.names.index(material.blend.material), texture)
            if material.bump is not None:
                self.bump[m] = (material.bump.height,
                                _Texture(read_texture(material.bump.texture.file),
                                         material.bump.texture))

    @property
    def empty(self) -> bool:
        """True when no material has a blend or a bump."""
        return not self.blend and not self.bump

    def _uv_gradients(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray] | None:
        """The mesh's per-face ∇u, ∇v (computed once per mesh), None when no texture
        reads the mesh's uv."""
        textures = [t for _, t in (*self.blend.values(), *self.bump.values())]
        if not any(t.mapping.projection == "uv" for t in textures):
            return None
        if self._gradients is None or self._gradients[0] is not mesh:
            self._gradients = (mesh, uv_gradients(mesh.vertices, mesh.uv, mesh.faces))
        return self._gradients[1]

    def at(self, surface: Surface) -> SurfaceDetail:
        """The detail at every hit of ``surface`` (see the module docstring)."""
        material = np.asarray(surface.material_id, np.int64)
        material_b = material.copy()
        blend = np.zeros(len(material))
        normal = np.asarray(surface.normal, np.float64)
        tangent = surface.tangent
        gradients = self._uv_gradients(surface.mesh)
        for m, (other, texture) in self.blend.items():
            which = np.flatnonzero(material == m)
            if len(which):
                material_b[which] = other
                blend[which] = np.clip(texture.at(gradients, surface, which)[0], 0.0, 1.0)
        bumped = np.zeros(len(material), bool)
        normal = normal.copy()
        for m, (height, texture) in self.bump.items():
            which = np.flatnonzero(material == m)
            if not len(which):
                continue
            _, gradient = texture.at(gradients, surface, which)
            outward = np.sign(np.sum(normal[which] * surface.mesh.face_normal[surface.face[which]],
                                     1))[:, None]
            normal[which] = bumped_normal(normal[which], outward * height * gradient)
            bumped[which] = True
        if bumped.any():
            tangent = np.where(bumped[:, None], orthonormalize(tangent, normal), tangent)
        return SurfaceDetail(normal, tangent, material, material_b, blend)
