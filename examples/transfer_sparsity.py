"""Example (pipeline.engine.inspect): how sparse method d2i's glossy transfer T is, per PCA basis
(paper 000 §5) — for the rows of basis b0 (the mean), b1, … b_k of every glossy pixel:
the coefficients each row keeps, how many rows' Haar coefficients reach the cap (the exact
near entries come on top of it), and the part of the row's norm that was dropped; the
diffuse rows D beside them.

    python examples/transfer_sparsity.py WORKDIR [--stage d2i.transfer] [--out sparsity.png]

WORKDIR a work directory holding ``d2i.transfer_t`` (T) and ``d2i.transfer`` (D)
(``prt run --until d2i.transfer_t`` bakes them for the default Cornell box); ``--stage
d2i.truncate`` shows the rows cut to the renderer's budgets instead, from
``d2i.truncate_t`` and ``d2i.truncate`` (no residuals there; D's rows there are rows of
pixel blocks). A pixel's T rows are consecutive, b0 first
(data_schema/d2i/glossy_transfer.yaml), so a row's basis is its place in its pixel's run.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from _example import parser, write_figure

from pipeline.engine import inspect
from pipeline.engine.rows import place_in_runs


def basis_of_rows(t_pixel: np.ndarray) -> np.ndarray:
    """The PCA basis (0 = b0) of each T row: its place in its pixel's run of rows."""
    return place_in_runs(t_pixel)


def far_counts(count: np.ndarray, index: np.ndarray, haar_length: int) -> np.ndarray:
    """Per row, its Haar coefficients (index < haar_length): what the cap limits; the
    row's near entries (index haar_length + g) come on top."""
    row = np.repeat(np.arange(len(count)), count)
    return np.bincount(row[index < haar_length], minlength=len(count))


def sparsity(workdir: Path, stage: str = "d2i.transfer") -> dict:
    """Per basis b (and ``"D"``): each row's coefficient count, its Haar coefficients
    alone (``far``), for d2i.transfer its residual, and the cap of its stage (T's and
    D's differ); the gather count. T's rows are read from ``stage``'s glossy twin
    (``{stage}_t``), D's from ``stage``."""
    work = inspect.open_workdir(workdir)
    ds, d_rows = work.dataset(f"{stage}_t"), work.dataset(stage)
    haar = int(ds.attrs["haar_length"])
    basis = basis_of_rows(ds["t_pixel"].values)
    counts = ds["t_count"].values
    far = far_counts(counts, ds["t_index"].values, haar)
    residual = ds["t_residual"].values if "t_residual" in ds else None
    t_cap = ds.attrs.get("max_coefficients") or ds.attrs.get("coefficients")
    rows = {}
    for b in range(int(basis.max()) + 1 if len(basis) else 0):
        pick = basis == b
        rows[f"b{b}"] = {"count": counts[pick], "far": far[pick], "cap": t_cap,
                         "residual": None if residual is None else residual[pick]}
    d_count = d_rows["d_count"].values
    rows["D"] = {"count": d_count, "far": far_counts(d_count, d_rows["d_index"].values, haar),
                 "cap": d_rows.attrs.get("max_coefficients"),
                 "residual": d_rows["d_residual"].values if "d_residual" in d_rows else None}
    return {"rows": rows, "gathers": int(ds.attrs["gather_count"])}


def main() -> None:
    ap = parser(__doc__, "sparsity.png")
    ap.add_argument("--stage", default="d2i.transfer",
                    choices=["d2i.transfer", "d2i.truncate"])
    args = ap.parse_args()
    s = sparsity(args.workdir, args.stage)
    names = list(s["rows"])
    counts = [s["rows"][n]["count"][s["rows"][n]["count"] > 0] for n in names]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].boxplot(counts, showfliers=False)
    axes[0].set_xticks(range(1, len(names) + 1), names)
    caps = [s["rows"][n]["cap"] for n in names]
    for i, cap in enumerate(caps, start=1):
        if cap:
            axes[0].hlines(cap, i - 0.4, i + 0.4, ls=":", color="k",
                           label="cap" if i == 1 else None)
    if any(caps):
        axes[0].legend(fontsize=8)
    axes[0].set_ylabel("coefficients per row")
    axes[0].set_title(f"kept of {s['gathers']} gathers (+ near entries)")
    fars = [s["rows"][n]["far"][s["rows"][n]["count"] > 0] for n in names]
    capped = [float((f >= cap).mean()) if cap and len(f) else 0.0
              for f, cap in zip(fars, caps, strict=True)]
    axes[1].bar(names, capped)
    axes[1].set_ylim(0, 1)
    axes[1].set_title("rows whose Haar coefficients reach the cap")
    residuals = [s["rows"][n]["residual"] for n in names]
    if all(r is not None for r in residuals):
        axes[2].boxplot([r[s["rows"][n]["count"] > 0] for n, r in zip(names, residuals,
                                                                       strict=True)],
                        showfliers=False)
        axes[2].set_xticks(range(1, len(names) + 1), names)
        axes[2].set_title("dropped part of each row's norm")
    else:
        axes[2].set_axis_off()
        axes[2].text(0.5, 0.5, f"{args.stage} keeps no residuals", ha="center")
    write_figure(fig, args.out, f"{len(names) - 1} PCA bases and D, {args.stage}")


if __name__ == "__main__":
    main()
