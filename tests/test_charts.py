"""Charts of evaluate records (pipeline/evaluation/charts.py) and the evaluate summary table, on
synthetic records: no bake, a few seconds."""

from __future__ import annotations

import numpy as np
from PIL import Image

from pipeline.evaluation.charts import bake_costs, heatmap, write_charts
from pipeline.evaluation.evaluate import summary_lines


def _record(tolerance: float, error: float, frame_ms: float, truncate_s: float,
            default: bool = False) -> dict:
    """A d2i-like record of a truncate.tolerance sweep: only d2i.truncate differs (its
    key and seconds); the upstream stages are shared, with the same keys."""
    stages = {"geometry": {"key": "g", "seconds": 2.0, "ran": False},
              "d2i.transfer": {"key": "t", "seconds": 40.0, "ran": False},
              "d2i.truncate": {"key": f"k{tolerance}", "seconds": truncate_s, "ran": True}}
    return {"method": "d2i", "headline": "rel_rmse_surfaces", "default": default,
            "budget": {"gather.count": 4096, "truncate.tolerance": tolerance},
            "rel_rmse_surfaces": error, "reference_rel_rmse_surfaces": 0.004,
            "model_rel_rmse_surfaces": error + 0.05,
            "rel_rmse_indirect": 2 * error, "reference_rel_rmse_indirect": 0.01,
            "frame_ms": frame_ms, "storage_bytes": int(1e6 / tolerance),
            "bake_s": 42.0 + truncate_s, "bake_stages": stages,
            "pathtrace_ms_equal_error": 300.0 * frame_ms}


RECORDS = [_record(0.005, 0.020, 3.0, 1.5), _record(0.02, 0.030, 9.0, 1.2, True),
           _record(0.08, 0.060, 40.0, 1.0)]


def test_bake_costs_count_only_the_stages_that_differ():
    """A sweep that re-runs one stage charts that stage's seconds; the stages every
    budget shares are reported once, not added to each point."""
    xs, varying, shared = bake_costs(RECORDS)
    assert xs == [1.5, 1.2, 1.0] and varying == ["d2i.truncate"]
    assert shared == {"d2i.transfer": 40.0, "geometry": 2.0}
    same = [dict(r, bake_stages={"geometry": r["bake_stages"]["geometry"]}) for r in RECORDS]
    assert bake_costs(same) == ([2.0, 2.0, 2.0], [], {})


def test_write_charts_draws_every_chart(tmp_path):
    """Headline and component charts, each a PNG with content (not one colour)."""
    written = write_charts(RECORDS, tmp_path)
    names = sorted(p.name for p in written)
    assert names == sorted([f"{p}error_vs_{c}.png" for p in ("", "indirect_")
                            for c in ("frame_time", "storage", "bake_time")])
    for path in written:
        pixels = np.asarray(Image.open(path).convert("L"))
        assert pixels.shape[0] > 300 and pixels.std() > 10


def test_heatmap_has_a_colour_bar(tmp_path):
    """The heat map figure is wider than the image's own aspect (the colour bar beside
    it)."""
    values = np.tile(np.linspace(0.0, 0.3, 64), (64, 1))  # 0 to 30 % across
    path = heatmap(tmp_path / "h.png", values, 0.2, "relative error")
    rgb = np.asarray(Image.open(path).convert("RGB"))
    assert rgb.shape[1] > 1.15 * rgb.shape[0]


def test_summary_lines_one_per_budget():
    """The summary names every budget with its headline error, the reference's own
    error, the error against full path tracing and the bake seconds of the stages that
    budget ran."""
    lines = summary_lines(RECORDS)
    assert len(lines) == 2 + len(RECORDS)
    assert lines[0].split()[:4] == ["budget", "error", "ref.", "full"]
    row = lines[2]  # the default budget
    assert row.split()[:3] == ["gather-count-4096_truncate-tolerance-0.02", "*", "0.0300"]
    assert row.split()[3:5] == ["0.0040", "0.0800"] and row.split()[-1] == "1.2"


def test_point_labels_never_overlap():
    """Budget labels overlap neither each other nor a point: three points well apart
    get their budgets; eight in a cluster (a grid sweep whose frames cost about the
    same) get numbers, and a key beside the axes lists the budgets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.evaluation.charts import _place_labels

    labels = [f"gather.count={g}, truncate.tolerance={t}"
              for g in (4096, 16384) for t in (0.005, 0.01, 0.02, 0.04)]
    for n, step in ((3, 30.0), (8, 0.6)):
        fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=120)
        ax.set_xlim(0, 100)
        ax.set_ylim(0, 100)
        xs, ys = 10 + step * np.arange(n), 10 + step * np.arange(n)
        ax.plot(xs, ys, "o")
        points = list(zip(xs, ys, labels[:n], strict=True))
        _place_labels(fig, ax, points, [(x, y) for x, y, _ in points])
        renderer = fig.canvas.get_renderer()
        marks = [ax.transData.transform((x, y)) for x, y in zip(xs, ys, strict=True)]
        texts = [t for t in ax.texts if "\n" not in t.get_text()]
        boxes = [t.get_window_extent(renderer) for t in texts]
        assert len(boxes) == n
        for i, a in enumerate(boxes):
            assert not any(a.overlaps(b) for b in boxes[i + 1:])
            assert not any(a.contains(px, py) for px, py in marks)
        numbered = [t.get_text() for t in texts] == [str(i + 1) for i in range(n)]
        keys = [t.get_text() for t in ax.texts if "\n" in t.get_text()]
        assert numbered == (n == 8) and len(keys) == (n == 8)
        plt.close(fig)
