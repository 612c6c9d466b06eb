"""Example (pipeline.engine.inspect): method triple's visibility textures (paper 004 §3.1) — per
texel, the fraction of its upper hemisphere from which the environment reaches it (1:
open sky, 0: fully occluded), from the stored wavelet rows, one panel per object.

    python examples/visibility_texture.py WORKDIR [--view WxH] [--out visibility.png]

WORKDIR a work directory holding ``triple.visibility`` and ``triple.atlas`` (``prt run
scenes/bunny_grace.yaml`` bakes them); WxH the image size of the bake when the work
directory holds bakes at several (default: the only one, or the camera's).

The fraction is read off the 20 scaling coefficients alone: with the basis orthonormal
over the sphere, root r's scaling coefficient is c_r = V̄_r √A_r (V̄_r the mean of V
over root triangle r, A_r its solid angle), so ∫V dω = Σ_r c_r √A_r, and the
hemisphere's 2π normalises it (data_schema/triple/triple_visibility.yaml; the basis:
pipeline/math/sphwavelet.py). Empty texels (outside every chart) are grey; a fully
occluded texel stores no coefficient and reads 0.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from _example import parser, write_figure

from pipeline.engine import inspect
from pipeline.errors import PrtError
from pipeline.math.sphwavelet import ROOTS, wavelet_basis


def artifact_name(workdir: Path, stage: str, view: str | None) -> str:
    """``stage`` or ``stage@WxH``, whichever the work directory holds (``view`` picks)."""
    names = [n for n in inspect.open_workdir(workdir).artifacts()
             if n == stage or n.startswith(f"{stage}@")]
    if view is not None:
        names = [n for n in names if n == f"{stage}@{view}"]
    if not names:
        raise PrtError(workdir, f"no {stage} artifact{f' at {view}' if view else ''}; bake "
                       "a scene with method triple first")
    return names[0]


def open_fractions(workdir: Path, view: str | None = None) -> dict[str, np.ndarray]:
    """Object -> its texture (height, width) of visible hemisphere fractions (NaN where
    a texel is empty)."""
    work = inspect.open_workdir(workdir)
    vis = work.dataset(artifact_name(workdir, "triple.visibility", view))
    atlas = work.dataset(artifact_name(workdir, "triple.atlas", view))
    roots = np.sqrt(wavelet_basis(int(vis.attrs["leaf_level"])).support_areas()[:ROOTS])
    count = vis["count"].values
    index, value = vis["index"].values, vis["value"].values
    row = np.repeat(np.arange(len(count)), count)
    scaling = index < ROOTS
    integral = np.bincount(row[scaling], value[scaling] * roots[index[scaling]],
                           minlength=len(count))
    texel_row, offsets = vis["texel_row"].values, atlas["texture_offsets"].values
    # a row with no coefficients is a fully occluded texel, or an empty one
    fraction = np.where(atlas["texel_state"].values > 0, integral[texel_row] / (2 * np.pi),
                        np.nan)
    out = {}
    for name, offset in zip(vis.attrs["texture_sizes"], offsets, strict=True):
        height, width = vis.attrs["texture_sizes"][name]
        out[name] = fraction[offset:offset + height * width].reshape(height, width)
    return out


def main() -> None:
    ap = parser(__doc__, "visibility.png")
    ap.add_argument("--view", metavar="WxH", help="the bake's image size, if several")
    args = ap.parse_args()
    fractions = open_fractions(args.workdir, args.view)
    fig, axes = plt.subplots(1, len(fractions), figsize=(3.6 * len(fractions) + 1, 3.8),
                             squeeze=False, layout="constrained")
    cmap = plt.get_cmap("magma").with_extremes(bad="0.6")
    for ax, (name, texture) in zip(axes[0], fractions.items(), strict=True):
        image = ax.imshow(texture, cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
        ax.set_title(f"{name} ({texture.shape[1]}×{texture.shape[0]})")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(image, ax=axes[0].tolist(), shrink=0.8, label="visible fraction of the "
                 "hemisphere")
    write_figure(fig, args.out, f"visibility of {len(fractions)} objects' textures")


if __name__ == "__main__":
    main()
