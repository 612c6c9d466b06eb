"""Chart: d2i's indirect error against D's storage, D cut per pixel row (paper 000's
proportional budget) and across 4 × 4 pixel blocks (truncate.d_block 4, a budget per
block: truncate.shared_budget block), from the
summaries of two d2i_accuracy.py sweeps over truncate.d_coefficients (Cornell box 128²,
16k gathers, references at 1024 spp; noise-corrected errors).

  python studies/d2i_storage_chart.py [--out PNG]
Reads benchmarks/results/d2i_accuracy/issue19/{d_budget,d_blocks}/summary.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "d2i_accuracy" / "issue19"
CURVES = {"d_budget": "per pixel row (paper 000)",
          "d_blocks": "across 4 × 4 pixel blocks (a budget per block)"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=RESULTS / "d_storage_chart.png")
    args = parser.parse_args()
    fig, (error_axis, mean_axis) = plt.subplots(1, 2, figsize=(10, 4))
    for folder, label in CURVES.items():
        runs = sorted(json.loads((RESULTS / folder / "summary.json").read_text())["runs"],
                      key=lambda r: r["d_mb_on_disk"])
        mb = [r["d_mb_on_disk"] for r in runs]
        error_axis.plot(mb, [100 * r["indirect_noise_corrected"] for r in runs], "o-",
                        label=label)
        mean_axis.plot(mb, [r["indirect_mean_ratio"] for r in runs], "o-", label=label)
        for r in runs:
            error_axis.annotate(str(r["d_coefficients"]), (r["d_mb_on_disk"],
                                100 * r["indirect_noise_corrected"]), fontsize=7,
                                xytext=(3, 3), textcoords="offset points")
    error_axis.set(xlabel="D on disk at 128² (MB)", ylabel="indirect error (%)",
                   title="indirect image error (labels: coefficients per pixel)")
    mean_axis.set(xlabel="D on disk at 128² (MB)", ylabel="indirect mean / reference",
                  title="indirect light kept")
    mean_axis.axhline(0.98, color="grey", lw=0.8, ls="--")
    for axis in (error_axis, mean_axis):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
