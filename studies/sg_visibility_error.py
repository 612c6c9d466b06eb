"""Study (issue 42, item 4; decision 0046): method sg's glossy light with no lobes — the
BRDF at the pixel's normal against each corner's visibility map — noise free, on the
pixels of studies/sg_glossy_error.py (its ``setup``: 160 random glossy pixels at 64²,
seed 0, the truth E0 by quadrature on a 1° grid).

Run from the project root:
    python studies/sg_visibility_error.py [--scenes bunny_sg dragon_sg] [--size 64]
        [--pixels 160] [--resolutions 16 32 64]
Writes benchmarks/results/sg_visibility_error.json.

Rows, each ‖E − E0‖ / ‖E0‖ over the pixels and channels (mean ratio ΣE / ΣE0):

* ``points_only``: Σ_a f_a R(x_a, n_p, ωo), the exact radiance at the corners' points
  (their visibility and occluders) with the pixel's normal: the floor of any per-vertex
  visibility (0037's (a) points-only row).
* ``nodes_exact_visibility``: the built estimator (pipeline/methods/sg/visibility.py
  ``glossy``) with each node's visibility the node Gaussian's mean of the corner's exact
  visibility on the 1° grid, the occluders' radiance by 4096 cosine rays: what the split
  and the node products cost, apart from the maps.
* ``built_R<r>``: the estimator as rendered, the stage's maps (r² texels, 2² rays each,
  uint8 pyramid) and occluder transfer (256 rays), the fitted BRDF lobe and the stack.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies"))

from sg_glossy_error import rel, setup  # noqa: E402

from pipeline.device.threads import one_blas_thread  # noqa: E402
from pipeline.math import sh  # noqa: E402
from pipeline.methods.sg import visibility  # noqa: E402
from pipeline.methods.sg.brdf_lobe import brdf_lobe, lobe_table  # noqa: E402

OUT = ROOT / "benchmarks" / "results"


class NodeMeans:
    """Exact visibility averaged by each node Gaussian: ``lookup``'s stand-in (same
    signature) over per-vertex escape masks on the truth's fine grid."""

    def __init__(self, truth, vscene, vertices: np.ndarray):
        self.dirs, self.omega = truth.dirs, truth.omega
        self.escape = {}
        for q in vertices:
            s, _, miss = truth.incoming(vscene.positions[q], vscene.normals[q])
            v = np.zeros(len(self.dirs))
            v[s[miss]] = 1.0
            self.escape[int(q)] = v

    def __call__(self, maps, resolution, vertex, directions, sigma):
        out = np.empty(len(vertex))
        for i, (q, d, s) in enumerate(zip(vertex, directions, sigma, strict=True)):
            g = np.exp((self.dirs @ d - 1.0) / s ** 2) * self.omega
            out[i] = (self.escape[int(q)] @ g) / g.sum()
        return out


def study(name: str, size: int, pixels: int, resolutions: list[int]) -> dict:
    c = setup(name, size, pixels, (181, 360), 0)
    truth, P, vs = c.truth, c.P, c.vscene
    e0 = np.array([truth.radiance(c.x[p], c.nrm[p], c.wo[p][None])[0][0] for p in range(P)])
    points = np.zeros((P, 3))
    for p in range(P):
        for a in range(3):
            q = int(c.corner[p, a])
            points[p] += c.bary[p, a] * truth.radiance(vs.positions[q], c.nrm[p],
                                                       c.wo[p][None])[0][0]
    verts = np.unique(c.corner)
    local = np.searchsorted(verts, c.corner)
    light_sh = sh.project_latlong(c.env, order=c.order)
    brdf = replace(c.brdf, albedo=(0.0, 0.0, 0.0))
    mu, lam, _ = brdf_lobe(lobe_table(brdf), c.nrm, c.wo)
    weights = visibility.node_weights(visibility.node_table(brdf), np.sum(c.nrm * c.wo, 1))
    specular = np.tile(np.asarray(c.brdf.specular, np.float64), (P, 1))

    def occluder(samples: int) -> np.ndarray:
        o = visibility.occluder_transfer(vs, verts, c.transfer, samples,
                                         np.random.default_rng(1))
        return np.maximum(np.einsum("vck,kc->vc", o, light_sh), 0.0)

    def glossy(maps, resolution, occ):
        return visibility.glossy(maps, resolution, occ, local, c.bary, c.nrm, mu, lam,
                                 weights, specular, c.stack, c.levels, np.eye(3))

    norm = float(np.sqrt(np.sum(e0 ** 2)))
    rows = {"points_only": rel(points, e0, norm)}
    exact = NodeMeans(truth, vs, verts)
    built_lookup = visibility.lookup
    try:
        visibility.lookup = lambda m, r, v, d, s: exact(m, r, verts[v], d, s)
        rows["nodes_exact_visibility"] = rel(glossy(None, 0, occluder(4096)), e0, norm)
    finally:
        visibility.lookup = built_lookup
    occ = occluder(256)
    for r in resolutions:
        maps = visibility.pyramid(visibility.visibility_maps(vs, verts, r, 2))
        rows[f"built_R{r}"] = rel(glossy(maps, r, occ), e0, norm)
    for k, v in rows.items():
        print(f"{name} {k:24s} {100 * v['rel_rmse']:5.1f} % (mean ratio {v['mean_ratio']:.3f})",
              flush=True)
    return {"scene": name, "size": size, "pixels": P, "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["bunny_sg", "dragon_sg"])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--pixels", type=int, default=160)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--out", default=str(OUT / "sg_visibility_error.json"))
    args = ap.parse_args()
    one_blas_thread()
    OUT.mkdir(parents=True, exist_ok=True)
    reports = [study(s, args.size, args.pixels, args.resolutions) for s in args.scenes]
    Path(args.out).write_text(json.dumps({"args": vars(args), "scenes": reports}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
