"""Write the shipped assets of the surface-detail scenes (aniso_sphere.yaml,
sbrdf_bump.yaml); run from anywhere: ``python scenes/make_surface_detail_assets.py``.

* ``meshes/uv_sphere.obj``: a unit sphere with latitude-longitude uv, 64 segments ×
  32 rings. u = φ/2π (φ the azimuth about +y from +x towards −z), v = 1 − θ/π (θ from
  +y): dP/du, the tangent every renderer uses (pipeline/device/raytrace.py ``Surface.tangent``),
  follows the circles of latitude eastwards (the anisotropic Ward's αx axis), dP/dv the
  meridians north. The seam (u = 0 = 1, the +x meridian) is split (its vertices
  doubled); the scenes' cameras on +z see it edge-on at the sphere's right silhouette.
  Each pole is one vertex per segment (at that segment's mid u). Vertex normals are
  computed by the geometry stage from the faces: 0.16° (median) off the true normal,
  3.0° at worst at the seam and the poles, where a vertex sees faces on one side only.
* ``textures/checker.png``: 64 × 64 8-bit grey, 8 × 8 checks of 0 and 255 (a blend's
  weight: 0 = the material itself, 1 = the one it blends with).
* ``textures/ridges.png``: 256 × 16 8-bit grey, h = ½ + ½ sin(2π · 16 u) (16 vertical
  ridges around the sphere: a bump map's heights, 0–255 read as 0–1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent
SEGMENTS, RINGS = 64, 32


def uv_sphere() -> str:
    """The OBJ text of the unit uv sphere."""
    lines = ["# unit sphere, lat-long uv (scenes/make_surface_detail_assets.py)"]
    vertices, uvs = [], []
    index = {}
    for i in range(RINGS + 1):
        theta = np.pi * i / RINGS
        columns = range(SEGMENTS) if i in (0, RINGS) else range(SEGMENTS + 1)
        for j in columns:
            u = (j + 0.5) / SEGMENTS if i in (0, RINGS) else j / SEGMENTS
            phi = 2 * np.pi * u
            vertices.append((np.sin(theta) * np.cos(phi), np.cos(theta),
                             -np.sin(theta) * np.sin(phi)))
            uvs.append((u, 1.0 - i / RINGS))
            index[i, j] = len(vertices)  # OBJ indices start at 1
    faces = []
    for j in range(SEGMENTS):
        faces.append((index[0, j], index[1, j], index[1, j + 1]))
        faces.append((index[RINGS - 1, j], index[RINGS, j], index[RINGS - 1, j + 1]))
        for i in range(1, RINGS - 1):
            a, b = index[i, j], index[i, j + 1]
            c, d = index[i + 1, j], index[i + 1, j + 1]
            faces += [(a, c, d), (a, d, b)]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def main() -> None:
    (HERE / "meshes").mkdir(exist_ok=True)
    (HERE / "textures").mkdir(exist_ok=True)
    (HERE / "meshes" / "uv_sphere.obj").write_text(uv_sphere())
    i, j = np.mgrid[0:64, 0:64]
    checker = ((i // 8 + j // 8) % 2 * 255).astype(np.uint8)
    Image.fromarray(checker, "L").save(HERE / "textures" / "checker.png", optimize=True)
    u = (np.arange(256) + 0.5) / 256
    ridges = np.round(255 * (0.5 + 0.5 * np.sin(2 * np.pi * 16 * u)))
    Image.fromarray(np.tile(ridges, (16, 1)).astype(np.uint8), "L").save(
        HERE / "textures" / "ridges.png", optimize=True)


if __name__ == "__main__":
    main()
