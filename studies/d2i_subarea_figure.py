"""Paper 000 Fig. 2 for this project: d2i's indirect image with and without sub-area
sampling beside the reference, the per-pixel error of each, and the glossy floor's error
in the titles.

Reads two runs of studies/d2i_accuracy.py on the same scene and reference (``--with``:
default settings; ``--without``: ``--set transfer.subarea_solid_angle=1e9``, every
gather sample a point) — their JSON and the PNGs beside them — and writes one PNG:

    python studies/d2i_subarea_figure.py --with W.json --without WO.json --out FIG.png
"""

from __future__ import annotations

import json
from pathlib import Path

import click


@click.command()
@click.option("--with", "with_path", type=click.Path(path_type=Path, exists=True),
              required=True)
@click.option("--without", "without_path", type=click.Path(path_type=Path, exists=True),
              required=True)
@click.option("--object", "glossy", default="floor", show_default=True,
              help="The glossy object whose indirect error the titles give.")
@click.option("--out", type=click.Path(path_type=Path), required=True)
def main(with_path: Path, without_path: Path, glossy: str, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {"with sub-area sampling": with_path, "without (point samples)": without_path}
    fig, axes = plt.subplots(2, 3, figsize=(10.5, 8.2), dpi=110)
    for column, (label, path) in enumerate(runs.items()):
        result = json.loads(path.read_text())
        stem = path.with_suffix("")
        glossy_error = result["per_object_indirect"][glossy]
        title = (f"{label}\n{glossy}: {glossy_error['rel_rmse']:.1%} rel. RMSE "
                 f"({glossy_error['noise_corrected']:.1%} without the reference's noise)\n"
                 f"whole indirect image: {result['indirect']['rel_rmse']:.1%}")
        axes[0, column].imshow(plt.imread(f"{stem}_indirect.png"))
        axes[0, column].set_title(title, fontsize=8)
        axes[1, column].imshow(plt.imread(f"{stem}_indirect_error.png"))
        axes[1, column].set_title("per-pixel error, 0 (black) to 50 % (white)", fontsize=8)
    reference = with_path.with_suffix("")
    axes[0, 2].imshow(plt.imread(f"{reference}_indirect_reference.png"))
    spp = json.loads(with_path.read_text())["spp"]
    axes[0, 2].set_title(f"reference (first-glossy-indirect, {spp} spp)", fontsize=8)
    axes[1, 2].axis("off")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle("Indirect light (×4), glossy Blinn-Phong floor (γ = 20)", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


if __name__ == "__main__":
    main()
