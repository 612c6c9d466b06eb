"""Spherical wavelets for method triple: what the paper's equal-area rules cost, and
top-only against adaptive truncation (paper 004 §3.1, §5, Fig. 7).

Run from the project root:  python studies/sphwavelet_study.py [--trials 40]
Writes ``benchmarks/results/sphwavelet_study.json`` and ``.png``.

Each trial is one shading point in its local frame (z = normal): L is the Grace
Cathedral map (``${PRT_DATA}/envmaps/grace_latlong_1024x512.exr``) turned by a random
rotation; V is the upper hemisphere less one or two random spherical caps (hard-edged
occluders, 5°–40° radius); ρ̃ = Blinn-Phong (γ random in [5, 200]) × cos θi at a random
ωo. The exact triple product ∫ L V ρ̃ is a 1.3 M-cell quadrature (level 8 of the
geodesic sphere, cell centroids). Against it:

* ``orthonormal``: the leaf means of level 4 (5120 leaves), transformed with the
  area-corrected basis, all coefficients (= Σ_leaf Ω_leaf L̄ V̄ ρ̄; only projection error);
* ``paper_centres``: paper 004 as published: the functions sampled at the 5120 leaf
  centres, its equal-area basis and tripling theorem (= Σ_leaf 4π/5120 · L V ρ̃);
* ``paper_means``: the equal-area rules on the leaf means (the weight error alone);
* truncation of all three functions to n coefficients, relative to the untruncated
  product: ``top-only`` (the first n of the layout), ``adaptive`` (paper 004: the n
  largest area-weighted, |c|·√(support solid angle), which favours coarse levels) and
  ``adaptive-l2`` (the n largest |c|: the best L2 approximation of each function alone).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.images import read_environment  # noqa: E402
from pipeline.math.brdf import BrdfParams, evaluate  # noqa: E402
from pipeline.math.envmap import EnvironmentMap  # noqa: E402
from pipeline.math.geodesic import geodesic_levels  # noqa: E402
from pipeline.math.sphwavelet import equal_area_basis, leaf_means, wavelet_basis  # noqa: E402
from pipeline.scene.model import shared_data_dir  # noqa: E402

LEAF_LEVEL = 4
EXACT_LEVEL = 8
BUDGETS = (20, 80, 320, 1280)
OUT = Path(__file__).parent / "results"


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def trial_functions(rng: np.random.Generator, env: EnvironmentMap):
    """(L, V, ρ̃) as functions of local unit directions (M, 3) -> (M,) (luminance of L)."""
    rotation = random_rotation(rng)
    caps = []
    for _ in range(rng.integers(1, 3)):
        axis = rng.normal(size=3)
        axis[2] = abs(axis[2]) + 0.3
        caps.append((axis / np.linalg.norm(axis), np.cos(np.radians(rng.uniform(5, 40)))))
    gamma = float(rng.uniform(5, 200))
    wo = rng.normal(size=3)
    wo[2] = abs(wo[2]) + 0.2
    wo /= np.linalg.norm(wo)
    material = BrdfParams("blinn_phong", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), gamma)

    def light(d):
        return env.radiance(d @ rotation.T) @ np.array([0.2126, 0.7152, 0.0722])

    def visibility(d):
        v = (d[:, 2] > 0).astype(float)
        for axis, cos_radius in caps:
            v[d @ axis > cos_radius] = 0.0
        return v

    def brdf_cos(d):
        up = np.maximum(d[:, 2], 0.0)
        return evaluate(d, np.broadcast_to(wo, d.shape), material)[:, 0] * up

    return light, visibility, brdf_cos, {"gamma": gamma, "caps": len(caps)}


MODES = ("top-only", "adaptive", "adaptive-l2")


def truncated(c: np.ndarray, n: int, mode: str, support: np.ndarray) -> np.ndarray:
    """``c`` with all but the ``n`` coefficients ``mode`` keeps set to zero."""
    out = np.zeros_like(c)
    weight = np.sqrt(support) if mode == "adaptive" else 1.0
    keep = np.arange(n) if mode == "top-only" else np.argsort(-np.abs(c) * weight)[:n]
    out[keep] = c[keep]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    env = EnvironmentMap(read_environment(shared_data_dir() / "envmaps"
                                          / "grace_latlong_1024x512.exr"))
    basis, paper = wavelet_basis(LEAF_LEVEL), equal_area_basis(LEAF_LEVEL)
    fine = geodesic_levels(EXACT_LEVEL)[EXACT_LEVEL]
    centres = geodesic_levels(LEAF_LEVEL)[LEAF_LEVEL].centroids
    support = basis.support_areas()
    rows = []
    for trial in range(args.trials):
        functions = trial_functions(rng, env)
        funcs, info = functions[:3], functions[3]
        exact = float(np.sum(fine.areas * np.prod([f(fine.centroids) for f in funcs], 0)))
        means = [leaf_means(f, LEAF_LEVEL, refine=EXACT_LEVEL - LEAF_LEVEL) for f in funcs]
        coefficients = [basis.forward(m) for m in means]
        full = float(basis.triple_product(*coefficients))
        row = {**info, "exact": exact,
               "orthonormal": full / exact - 1,
               "paper_centres": float(paper.triple_product(
                   *[paper.forward(f(centres)) for f in funcs])) / exact - 1,
               "paper_means": float(paper.triple_product(
                   *[paper.forward(m) for m in means])) / exact - 1}
        for mode in MODES:
            row[mode] = {n: float(basis.triple_product(
                *[truncated(c, n, mode, support) for c in coefficients])) / full - 1
                for n in BUDGETS}
        rows.append(row)
        print(f"trial {trial + 1}/{args.trials}: orthonormal {row['orthonormal']:+.2e} "
              f"paper {row['paper_centres']:+.2e}  top-only 80 {row['top-only'][80]:+.3f} "
              f"adaptive 80 {row['adaptive'][80]:+.3f}", flush=True)

    def stats(values):
        a = np.abs(np.asarray(values))
        return {"median_abs": float(np.median(a)), "max_abs": float(a.max())}

    summary = {key: stats([r[key] for r in rows])
               for key in ("orthonormal", "paper_centres", "paper_means")}
    for mode in MODES:
        summary[mode] = {n: stats([r[mode][n] for r in rows]) for n in BUDGETS}
    OUT.mkdir(exist_ok=True)
    (OUT / "sphwavelet_study.json").write_text(json.dumps(
        {"leaf_level": LEAF_LEVEL, "exact_level": EXACT_LEVEL, "trials": args.trials,
         "seed": args.seed, "summary": summary, "rows": rows}, indent=1))
    fig, ax = plt.subplots(figsize=(6, 4))
    for mode, style in zip(MODES, ("o-", "s--", "^:"), strict=True):
        ax.loglog(BUDGETS, [summary[mode][n]["median_abs"] for n in BUDGETS], style,
                  label=f"{mode} (median)")
    for key, colour in (("paper_centres", "C3"), ("orthonormal", "C2")):
        ax.axhline(summary[key]["median_abs"], color=colour, lw=1,
                   label=f"{key.replace('_', ' ')}, all 5120 (median)")
    ax.set_xlabel("coefficients kept per function")
    ax.set_ylabel("|relative error| of ∫ L V ρ̃")
    ax.set_xticks(BUDGETS, [str(n) for n in BUDGETS])
    ax.legend(fontsize=8)
    ax.set_title(f"Triple products, {args.trials} random shading points")
    fig.tight_layout()
    fig.savefig(OUT / "sphwavelet_study.png", dpi=120)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
