"""Example (pipeline.engine.inspect): a material's PCA basis (method d2i, paper 000 §4) — the
mean edited BRDF term and the first k basis rows over the PCA coordinate, the singular
values, and the worst relative reconstruction error against k.

    python examples/brdf_basis.py WORKDIR [--material NAME] [--out basis.png]

WORKDIR a work directory holding ``brdf_basis`` (``prt run --until brdf_basis`` bakes it
for the default Cornell box in a second); NAME a glossy material (default: the first
with k > 0). The dotted line in the last panel is the material's tolerance; k is the
smallest count under it (data_schema/d2i/brdf_basis.yaml).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from _example import parser, write_figure

from pipeline.engine import inspect
from pipeline.errors import PrtError


def material_basis(workdir: Path, material: str | None = None) -> dict:
    """The material's arrays from ``brdf_basis`` (only its row is read): name, k,
    tolerance, grid, mean, the first k basis rows, singular values, worst rel_rms per k."""
    ds = inspect.open_workdir(workdir).dataset("brdf_basis")
    names = list(ds.attrs["material_names"])
    k_all = ds["k"].values
    if material is None:
        glossy = [n for n, k in zip(names, k_all, strict=True) if k > 0]
        if not glossy:
            raise PrtError(workdir, "brdf_basis: no material with a PCA basis (k > 0)")
        material = glossy[0]
    if material not in names:
        raise PrtError(workdir, f"brdf_basis: no material {material!r}; "
                       f"present: {', '.join(names)}")
    m = ds.isel(material=names.index(material))
    k = int(m["k"].values)
    tolerance = float(ds.attrs["tolerances"][names.index(material)])
    return {"name": material, "k": k, "tolerance": tolerance,
            "grid": m["grid"].values, "mean": m["mean"].values,
            "basis": m["basis"].values[:k], "singular_values": m["singular_values"].values,
            "worst_rel_rms": m["rel_rms"].values.max(axis=1)}


def main() -> None:
    ap = parser(__doc__, "basis.png")
    ap.add_argument("--material", help="a glossy material [default: the first with k > 0]")
    args = ap.parse_args()
    b = material_basis(args.workdir, args.material)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].plot(b["grid"], b["mean"], "k", lw=2, label="mean b₀")
    for i, row in enumerate(b["basis"]):
        axes[0].plot(b["grid"], row * np.abs(b["mean"]).max(), lw=1, label=f"b{i + 1} (scaled)")
    axes[0].set_xlabel("PCA coordinate x")
    axes[0].set_title(f"{b['name']}: mean and {b['k']} basis rows")
    axes[0].legend(fontsize=7)
    axes[1].semilogy(np.arange(1, len(b["singular_values"]) + 1), b["singular_values"], "o-")
    axes[1].set_xlabel("component")
    axes[1].set_title("singular values")
    axes[2].semilogy(np.arange(len(b["worst_rel_rms"])), b["worst_rel_rms"], "o-")
    axes[2].axhline(b["tolerance"], ls=":", color="k")
    axes[2].axvline(b["k"], ls="--", color="tab:red")
    axes[2].set_xlabel("k")
    axes[2].set_title("worst relative RMS over γ")
    write_figure(fig, args.out, f"{b['name']}, k = {b['k']}")


if __name__ == "__main__":
    main()
