"""Charts of ``prt evaluate`` records (pipeline/evaluation/evaluate.py) and error heat maps, drawn
with matplotlib (Agg, PNG).

Error charts: each method's error (log scale) against frame time, storage or bake time,
against the reference of its transport (solid) and against full path tracing (the model
error, dashed); one point per budget, labelled with the budget values that vary across the sweep and
placed where they overlap neither each other nor the points; the reference's own
estimated error as a dotted line (an error near it measures the reference, not the
method); the legend below the axes. Axes spanning more than a decade are logarithmic
with labelled ticks at 1, 2 and 5 of each decade (more when that gives fewer than three).

Bake time: a budget's bake is the compute of the stages that *differ* between the
sweep's budgets (their artifact keys differ), summed over their chunks
(:func:`bake_costs`); stages every budget shares are baked once and named in the axis
label with their seconds. A sweep that re-runs one stage thus charts that stage's cost,
not the noise of the chain's timings.

Heat maps: the per-pixel values with a colour bar in their units.
"""

from __future__ import annotations

import math
import os
import textwrap
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import PrtError

CHARTS = (("frame_ms", "frame time (ms, median)", "error_vs_frame_time.png"),
          ("storage_bytes", "storage a frame reads (MB; on disk, or as held where cut at run time)",
           "error_vs_storage.png"),
          ("bake_s", "bake time (s)", "error_vs_bake_time.png"))


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def headline(records: list[dict[str, Any]], method: str) -> str:
    """The headline error of ``method``'s records (as recorded with them)."""
    return next(r.get("headline", "rel_rmse") for r in records if r["method"] == method)


def reference_noise_key(error: str) -> str:
    """The record field holding the reference's own estimated error for ``error``
    (``rel_rmse_surfaces`` -> ``reference_rel_rmse_surfaces``)."""
    return f"reference_{error}"


def model_error_key(error: str) -> str:
    """The record field holding ``error`` measured against full path tracing (the
    model error: ``rel_rmse_surfaces`` -> ``model_rel_rmse_surfaces``)."""
    return f"model_{error}"


def bake_costs(records: list[dict[str, Any]]
               ) -> tuple[list[float], list[str], dict[str, float]]:
    """Per record, the compute seconds of the stages whose artifact differs between the
    records (``bake_stages``: per stage its key and seconds); the names of those stages;
    and the seconds of each stage all records share. With no stage differing (a sweep
    of run-time options), each record's cost is its whole bake and nothing is shared."""
    stages = sorted({s for r in records for s in r["bake_stages"]})
    varying = [s for s in stages
               if len({r["bake_stages"].get(s, {}).get("key") for r in records}) > 1]
    if not varying:
        return [sum(v["seconds"] for v in r["bake_stages"].values()) for r in records], \
            [], {}
    shared = {s: records[0]["bake_stages"][s]["seconds"] for s in stages if s not in varying}
    return [sum(r["bake_stages"][s]["seconds"] for s in varying if s in r["bake_stages"])
            for r in records], varying, shared


def write_charts(records: list[dict[str, Any]], out: Path) -> list[Path]:
    """Each method's headline error against frame time, storage and bake time (the
    frame-time chart also shows the path tracers' time to equal error), and, per
    component the records have (d2i: indirect), its error
    (``<component>_error_vs_*.png``). Returns the files written."""
    components = sorted({k[len("rel_rmse_"):] for r in records for k in r
                         if k.startswith("rel_rmse_") and k != "rel_rmse_surfaces"})
    written = []
    for key, label, name in CHARTS:
        written.append(error_chart(records, key, label, out / name, None))
        for component in components:
            error = f"rel_rmse_{component}"
            written.append(error_chart([r for r in records if error in r], key, label,
                                       out / f"{component}_{name}", error))
    return written


def suite_chart(rows: list[dict[str, Any]], method: str, size: str, path: Path) -> Path:
    """A method's scene suite (benchmarks/scene_suite.py): per scene, its headline error
    against full path tracing (the model error, solid) and against the reference of its
    transport (the method error, dashed) over the frame time at ``size`` (``WxH``), one
    point per budget, a colour per scene."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.2, 5.4), dpi=120)
    xs_all, ys_all = [], []
    for row in rows:
        records = sorted(row["budgets"], key=lambda r: r["frame_ms_at"][size]["frame_ms"])
        xs = [r["frame_ms_at"][size]["frame_ms"] for r in records]
        error = records[0]["headline"]
        model = [r[model_error_key(error)] for r in records]
        own = [r[error] for r in records]
        line, = ax.plot(xs, model, "o-", label=f"{row['scene']}")
        ax.plot(xs, own, "x--", color=line.get_color(), alpha=0.7)
        varying = _varying_budget(records)
        for x, y, r in zip(xs, model, records, strict=True):
            if r["default"]:
                ax.plot(x, y, "*", ms=13, color="gold", mec="k", zorder=5)
            ax.annotate(",".join(str(r["budget"][k]) for k in varying if k in r["budget"]),
                        (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7,
                        color=line.get_color())
        xs_all += xs * 2
        ys_all += model + own
    _log_axis(ax, "x", xs_all)
    _log_axis(ax, "y", ys_all)
    ax.set_xlabel(f"frame time at {size} (ms, median)")
    budgets = sorted({k for row in rows for r in row["budgets"] for k in r["budget"]})
    ax.set_ylabel(f"relative RMSE ({rows[0]['budgets'][0]['headline']})")
    ax.set_title(f"{method}: solid against full path tracing, dashed against its own "
                 f"transport; points labelled {', '.join(budgets)}; ★ default", fontsize=8)
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.15)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    _save(plt, fig, path)
    return path


def _varying_budget(records: list[dict[str, Any]]) -> list[str]:
    """The budget names whose values differ between records (the point labels)."""
    names = sorted({k for r in records for k in r["budget"]})
    return [n for n in names if len({str(r["budget"].get(n)) for r in records}) > 1]


def _x_values(rows: list[dict[str, Any]], key: str, label: str) -> tuple[list[float], str]:
    """The x of each record, and the axis label (bake time: see :func:`bake_costs`)."""
    if key == "storage_bytes":
        return [r[key] / 1e6 for r in rows], label
    if key != "bake_s" or not all("bake_stages" in r for r in rows):
        return [r[key] for r in rows], label
    xs, varying, shared = bake_costs(rows)
    if not varying:
        return xs, f"{label}: every budget shares one bake"
    shared_text = textwrap.fill(f"shared by every budget: {', '.join(shared)}, "
                                f"{sum(shared.values()):.1f} s", 80)
    return xs, f"bake time of {', '.join(varying)} (s, summed over chunks)\n{shared_text}"


def error_chart(records: list[dict[str, Any]], key: str, label: str, path: Path,
                error_key: str | None) -> Path:
    """One chart of error (``error_key``, or each method's headline) against ``key``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=120)
    points: list[tuple[float, float, str]] = []  # labelled budget points
    others: list[tuple[float, float]] = []  # other plotted points (tracers, noise)
    lines: list[list[tuple[float, float]]] = []  # plotted lines (data coordinates)
    levels: list[float] = []  # horizontal lines across the axes
    varying = _varying_budget(records)
    xlabel = label
    for method in sorted({r["method"] for r in records}):
        error = error_key or headline(records, method)
        rows = [r for r in records if r["method"] == method]
        xs, xlabel = _x_values(rows, key, label)
        order = np.argsort(xs, kind="stable")
        xs, rows = [xs[i] for i in order], [rows[i] for i in order]
        ys = [r[error] for r in rows]
        line, = ax.plot(xs, ys, "o-", label=f"{method} ({error}, its transport)")
        lines.append(list(zip(xs, ys, strict=True)))
        model = [r.get(model_error_key(error)) for r in rows]
        if error_key is None and all(m is not None for m in model):
            ax.plot(xs, model, "x--", color=line.get_color(),
                    label=f"{method} against full path tracing")
            lines.append(list(zip(xs, model, strict=True)))
            others += list(zip(xs, model, strict=True))
        noise = [r.get(reference_noise_key(error)) for r in rows]
        if all(n is not None and math.isfinite(n) for n in noise):
            legend = f"{method}: the reference's own estimated error"
            if max(noise) <= 1.01 * min(noise):  # one reference: a line across
                ax.axhline(noise[0], ls=":", color=line.get_color(), lw=1.5, label=legend)
                levels.append(noise[0])
            else:
                ax.plot(xs, noise, "_:", color=line.get_color(), lw=1.5, ms=10,
                        label=legend)
                lines.append(list(zip(xs, noise, strict=True)))
            others += list(zip(xs, noise, strict=True))
        for x, y, r in zip(xs, ys, rows, strict=True):
            points.append((x, y, ", ".join(f"{k}={r['budget'][k]}" for k in varying
                                           if k in r["budget"])))
            if r["default"]:
                ax.plot(x, y, "*", ms=14, color="gold", mec="k", zorder=5,
                        label="default budget")
        if key == "frame_ms" and error_key is None:
            for tracer, field_name in (("reference path tracer", "pathtrace_ms_equal_error"),
                                       ("Mitsuba 3", "mitsuba_ms_equal_error")):
                pts = sorted((r[field_name], r[error]) for r in rows if r.get(field_name))
                if pts:
                    ax.plot(*zip(*pts, strict=True), "s--", label=f"{tracer}, equal error")
                    others += pts
                    lines.append(pts)
    everything = [(x, y) for x, y, _ in points] + others
    _log_axis(ax, "x", [x for x, _ in everything])
    _log_axis(ax, "y", [y for _, y in everything])
    ax.set_xlabel(xlabel, fontsize=9)
    component = error_key[len("rel_rmse_"):] if error_key else None
    ax.set_ylabel("relative RMSE vs reference"
                  + (f" ({component} image)" if component else ""))
    ax.grid(True, which="major", alpha=0.4)
    ax.grid(True, which="minor", alpha=0.15)
    handles, names = ax.get_legend_handles_labels()
    unique = dict(zip(names, handles, strict=True))  # "default budget" once
    fig.tight_layout()
    fig.canvas.draw()  # final limits and layout: where points, texts and labels land
    below = ax.xaxis.get_tightbbox(fig.canvas.get_renderer())  # tick labels and label
    bottom = ax.transAxes.inverted().transform((0, below.y0))[1]
    ax.legend(unique.values(), unique.keys(), fontsize=8, loc="upper center",
              bbox_to_anchor=(0.5, bottom - 0.02), ncol=2, frameon=False)
    low, high = ax.get_xlim()
    lines += [[(low, y), (high, y)] for y in levels]
    _place_labels(fig, ax, points, everything, lines)
    _save(plt, fig, path)
    return path


def _log_axis(ax: Any, which: str, values: list[float]) -> None:
    """Logarithmic ``which`` axis when ``values`` span more than a decade (else linear);
    the y (error) axis is always logarithmic. Labels are plain numbers at 1 × 10^n over
    many decades, at 1, 3 or 1, 2, 5 × 10^n over fewer, at evenly spaced round numbers
    within less than a decade, so that an axis always has a few labelled ticks and
    they never crowd."""
    from matplotlib.ticker import (
        FuncFormatter,
        LogLocator,
        MaxNLocator,
        NullFormatter,
        NullLocator,
    )

    positive = [v for v in values if v is not None and v > 0 and math.isfinite(v)]
    if not positive:
        return
    low, high = min(positive), max(positive)
    if which == "x" and high <= 10 * low:
        ax.ticklabel_format(axis="x", style="plain", useOffset=False)
        return  # within a decade a linear axis reads best
    axis = ax.xaxis if which == "x" else ax.yaxis
    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    span = math.log10(high / low)
    # labelled ticks: fewer per decade as the axis spans more decades; within less than
    # a decade, evenly spaced round numbers (a log locator would label one or none)
    if span > 0.7:
        subs = (1.0,) if span > 3 else (1.0, 3.0) if span > 1.6 else (1.0, 2.0, 5.0)
        axis.set_major_locator(LogLocator(base=10, subs=subs))
        axis.set_minor_locator(LogLocator(base=10, subs=tuple(range(1, 10))))
    else:
        axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
        axis.set_minor_locator(NullLocator())
    axis.set_major_formatter(FuncFormatter(_plain))
    axis.set_minor_formatter(NullFormatter())
    pad = 10 ** (0.08 * max(span, 0.3))  # room for the markers and, above, a label
    (ax.set_xlim if which == "x" else ax.set_ylim)(low / pad,
                                                   high * pad ** (1 if which == "x" else 2))


def _plain(value: float, _: Any = None) -> str:
    """A tick label as a plain number: 0.005, 20, 3000 (no powers of ten)."""
    return f"{value:.0f}" if value >= 100 else f"{value:.3g}"


_MARK_RADIUS = 6.0  # points: the space a plotted marker (the default's star) takes
# where a label may go, in points from its point (right/left, above/below), nearest first
_OFFSETS = [(6, 6), (6, -12), (-6, 6), (-6, -12), (10, -3), (-10, -3), (6, 16), (6, -22),
            (-6, 16), (-6, -22), (6, 28), (6, -34), (-6, 28), (-6, -34)]


def _place_labels(fig: Any, ax: Any, points: list[tuple[float, float, str]],
                  marks: list[tuple[float, float]],
                  lines: list[list[tuple[float, float]]] = ()) -> None:
    """Label each point with its budget where the text overlaps no other label, no
    plotted marker or line, and stays inside the axes. When some label finds no such
    place (a cluster of points), the points get numbers instead and a key beside the
    axes lists what each number stands for. ``marks`` and ``lines`` are in data
    coordinates."""
    from matplotlib.transforms import Bbox

    fig.canvas.draw()  # final limits and layout: where points and texts land
    to_pixels = ax.transData.transform
    r = _MARK_RADIUS * fig.dpi / 72.0
    obstacles = [Bbox([[px - r, py - r], [px + r, py + r]])
                 for px, py in (to_pixels(p) for p in marks)]
    for line in lines:
        pixels = [to_pixels(p) for p in line]
        for (x0, y0), (x1, y1) in zip(pixels, pixels[1:], strict=False):
            steps = max(1, int(math.hypot(x1 - x0, y1 - y0) / 3.0))
            obstacles += [Bbox([[x - 1.5, y - 1.5], [x + 1.5, y + 1.5]]) for x, y in
                          zip(np.linspace(x0, x1, steps + 1), np.linspace(y0, y1, steps + 1),
                              strict=True)]
    if _try_labels(fig, ax, points, obstacles, force=False) is not None:
        return
    labelled = [p for p in points if p[2]]
    _try_labels(fig, ax, [(x, y, str(i + 1)) for i, (x, y, _) in enumerate(labelled)],
                obstacles, force=True)
    key = "\n".join(f"{i + 1}: {text}" for i, (_, _, text) in enumerate(labelled))
    ax.text(1.03, 1.0, key, transform=ax.transAxes, va="top", ha="left", fontsize=7)


def _try_labels(fig: Any, ax: Any, points: list[tuple[float, float, str]],
                obstacles: list[Any], force: bool) -> list[Any] | None:
    """Annotate each point at the first offset (in points) where its text overlaps none
    of ``obstacles`` (pixel boxes) nor a label placed before, inside the axes; None
    (and nothing drawn) if one is nowhere clear, unless ``force``: then it goes at the
    first offset on a white box."""
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    taken = list(obstacles)
    drawn: list[Any] = []
    for x, y, text in points:
        if not text:
            continue
        for dx, dy in _OFFSETS:
            ann = ax.annotate(text, (x, y), textcoords="offset points", xytext=(dx, dy),
                              fontsize=7, ha="left" if dx >= 0 else "right")
            box = ann.get_window_extent(renderer).expanded(1.05, 1.15)
            if (not any(box.overlaps(t) for t in taken)
                    and frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1)):
                break
            ann.remove()
        else:
            if not force:
                for artist in drawn:
                    artist.remove()
                return None
            ann = ax.annotate(text, (x, y), textcoords="offset points", xytext=_OFFSETS[0],
                              fontsize=7, bbox={"fc": "white", "ec": "none", "alpha": 0.8})
            box = ann.get_window_extent(renderer)
        taken.append(box)
        drawn.append(ann)
    return drawn


def _save(plt: Any, fig: Any, path: Path) -> None:
    """Write ``fig`` as a PNG under a temporary name, then rename it onto ``path``."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.png")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(tmp, bbox_inches="tight")
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise PrtError(path, f"cannot write chart ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)


def heatmap(path: Path, values: np.ndarray, vmax: float, label: str,
            title: str | None = None, percent: bool = False,
            colormap: str = "magma") -> Path:
    """(height, width) non-negative ``values`` as an image, 0 to ``vmax`` (above:
    clipped, the bar says so), with a colour bar labelled ``label`` (the units; with
    ``percent`` the values are fractions, labelled in %)."""
    plt = _pyplot()
    h, w = values.shape
    size = 4.0
    fig, ax = plt.subplots(figsize=(size * w / h + 1.3, size + 0.4), dpi=120)
    image = ax.imshow(np.nan_to_num(values), cmap=colormap, vmin=0.0, vmax=vmax,
                      interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=9)
    bar = fig.colorbar(image, ax=ax, fraction=0.05, pad=0.03,
                       extend="max" if np.nanmax(values) > vmax else "neither")
    bar.set_label(label, fontsize=8)
    if percent:
        from matplotlib.ticker import PercentFormatter

        bar.ax.yaxis.set_major_formatter(PercentFormatter(xmax=1.0))
    bar.ax.tick_params(labelsize=7)
    _save(plt, fig, path)
    return path
