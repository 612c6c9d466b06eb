"""Example (pipeline.engine.inspect): method sg's Gaussians over a mesh — per vertex, the lobe
count N and slot 0's width σ at the view nearest the vertex's normal, drawn at the
vertices' positions.

    python examples/sg_lobes_over_mesh.py WORKDIR [--stage sg.relax] [--out lobes.png]

WORKDIR a work directory baked for method sg (``prt run scenes/bunny_sg.yaml``). Two
panels, vertices projected onto the world x–y plane (+y up), glossy vertices only (those
that store a slot): N (1–3) and σ in degrees (sg_lobes: λ = 1/σ², stored in rad⁻²).
A vertex whose σ jumps against its neighbours' is where a highlight will pop; N > 1
marks transport one lobe could not represent (decision 0032).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from _example import parser, write_figure

from pipeline.engine import inspect


def normal_view_sigma(workdir: Path, stage: str = "sg.relax"
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Glossy vertices' indices (G,), positions (G, 3), counts (G,) and slot 0's σ in
    degrees at the view nearest each one's normal (G,)."""
    work = inspect.open_workdir(workdir)
    geometry, lobes = work.dataset("geometry"), work.dataset(stage)
    first = lobes["first"].values
    stored = np.diff(np.append(first, lobes.sizes["slot"]))
    glossy = np.flatnonzero(stored > 0)
    normals = geometry["normals"].values[glossy].astype(np.float64)
    nearest = np.argmax(normals @ lobes["views"].values.T, axis=1)        # (G,)
    slot0 = lobes["lobes"].data[first[glossy]]                            # lazy (G, 92, 7)
    lam = np.take_along_axis(np.asarray(slot0[..., 6]), nearest[:, None], axis=1)[:, 0]
    sigma = np.degrees(1.0 / np.sqrt(lam))
    return (glossy, geometry["vertices"].values[glossy], lobes["count"].values[glossy],
            sigma)


def main() -> None:
    ap = parser(__doc__, "lobes.png")
    ap.add_argument("--stage", default="sg.relax", choices=["sg.fit", "sg.relax"])
    args = ap.parse_args()
    _, position, count, sigma = normal_view_sigma(args.workdir, args.stage)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, values, title, cmap in ((axes[0], count, "lobes N", "viridis"),
                                    (axes[1], sigma, "σ of slot 0 at the normal view (°)",
                                     "magma")):
        dots = ax.scatter(position[:, 0], position[:, 1], c=values, s=2, cmap=cmap)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        fig.colorbar(dots, ax=ax, shrink=0.8)
    fig.suptitle(f"{args.stage}: {len(count)} glossy vertices")
    write_figure(fig, args.out, f"{len(count)} glossy vertices")


if __name__ == "__main__":
    main()
