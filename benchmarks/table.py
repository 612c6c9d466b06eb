"""The generated figures: ``docs/results.md`` (every method's accuracy sweep and the
other results found) and the "Current figures" section of each ``docs/methods/<m>.md``,
both from the JSON the benchmarks wrote (``python -m benchmarks table``).

A method page holds the line ``<!-- generated: ... -->``; everything from it to the next
heading is replaced by the method's table. The README's line of the same kind gets one
row per method: its default budget's figures.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from benchmarks.fixtures import ROOT

DOCS = ROOT / "docs"
METHODS = ("d2i", "triple", "sg")
MARKER = (
    "<!-- generated: the figures table for {m} is inserted here by python -m benchmarks table -->")
SUITE_MARKER = (
    "<!-- generated: the scene suite table for {m} is inserted here by python -m benchmarks "
    "table -->")
VIEW_MARKER = ("<!-- generated: prt view's latency table is inserted here by python -m "
               "benchmarks table -->")
README_MARKER = ("<!-- generated: the methods' headline figures are inserted here by python -m "
                 "benchmarks table -->")


def _budget(record: dict[str, Any]) -> str:
    text = ", ".join(f"{k.removeprefix('render.')}={v}" for k, v in record["budget"].items())
    return f"{text} (default)" if record.get("default") else text


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def _ms(x: float | None) -> str:
    return "–" if x is None else f"{x:.1f}" if x < 100 else f"{x:.0f}"


def accuracy_table(result: dict[str, Any]) -> list[str]:
    """Markdown lines: one row per budget of a ``<method>.accuracy`` result."""
    head = result["budgets"][0]["headline"] if result["budgets"] else "rel_rmse"
    m = result["machine"]
    lines = [f"`{result['method']}` on `{Path(result['scene']).name}` at "
             f"{result['size'][0]}×{result['size'][1]}, {m['cpu']} ({m['cores']} cores), "
             f"OpenCL {m.get('opencl_device', '?')}, load average "
             f"{result['load'][0][0]:g}–{result['load'][1][0]:g}, {result['finished']}; error "
             f"`{head}` against the reference of the method's transport (*method error*) "
             "and against full path tracing (*model error*: what a path tracer shows), "
             "each reference's own noise beside it:", "",
             "| budget | frame ms | method error | noise | model error | noise | read MB "
             "| bake s | path tracer ms at equal error |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in result["budgets"]:
        lines.append(f"| {_budget(r)} | {_ms(r['frame_ms'])} | {_pct(r[r['headline']])} | "
                     f"{_pct(r.get('reference_' + r['headline']))} | "
                     f"{_pct(r.get('model_' + r['headline']))} | "
                     f"{_pct(r.get('reference_model_' + r['headline']))} | "
                     f"{r['storage_bytes'] / 1e6:.1f} | {r['bake_s']:.0f} | "
                     f"{_ms(r.get('pathtrace_ms_equal_error'))} |")
    return lines


def suite_table(result: dict[str, Any]) -> list[str]:
    """Markdown lines: one row per scene and budget of a ``<method>.suite`` result
    (benchmarks/scene_suite.py)."""
    m = result["machine"]
    sizes = result["frame_sizes"]
    # a --scenes run keeps the other scenes' rows, each with its own time and load
    loads = [x[0] for row in result["scenes"] for x in row.get("load", result["load"])]
    times = sorted(row.get("finished", result["finished"]) for row in result["scenes"])
    when = times[0] if times[0] == times[-1] else f"{times[0]} to {times[-1]}"
    lines = [f"`{result['method']}` on its scene suite, errors at {result['size'][0]}×"
             f"{result['size'][1]} ({m['cpu']}, {m['cores']} cores, OpenCL "
             f"{m.get('opencl_device', '?')}, load average {min(loads):g}–{max(loads):g}, "
             f"{when}): the *method error* against "
             "the reference of its transport, the *model error* against full path tracing "
             "(each reference's own noise beside it), frame times at "
             f"{' and '.join(sizes)}; chart: `{Path(result['chart']).name}` beside the "
             "result.", "",
             "| scene | budget | method error | noise | model error | noise | "
             + " | ".join(f"frame ms {s}" for s in sizes) + " | read MB | bake s |",
             "|---|---|---|---|---|---|" + "---|" * len(sizes) + "---|---|"]
    for row in result["scenes"]:
        for r in row["budgets"]:
            head = r["headline"]
            times = " | ".join(_ms(r["frame_ms_at"][s]["frame_ms"]) for s in sizes)
            lines.append(f"| {row['scene']} | {_budget(r)} | {_pct(r[head])} | "
                         f"{_pct(r.get('reference_' + head))} | "
                         f"{_pct(r.get('model_' + head))} | "
                         f"{_pct(r.get('reference_model_' + head))} | {times} | "
                         f"{r['storage_bytes'] / 1e6:.1f} | {r['bake_s']:.0f} |")
    lines += ["", "Scenes: " + "; ".join(f"{row['scene']}: {row['why']}"
                                         for row in result["scenes"]) + "."]
    return lines


def headline_rows(results: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown lines: per method its default budget's figures (``results``: method ->
    its ``<method>.accuracy`` result)."""
    lines = ["| method | scene | size | error against full path tracing | against its "
             "transport | reference noise | frame ms | bake s | measured |",
             "|---|---|---|---|---|---|---|---|---|"]
    for m, result in results.items():
        r = next((b for b in result["budgets"] if b.get("default")), result["budgets"][-1])
        head = r["headline"]
        lines.append(f"| `{m}` | `{Path(result['scene']).name}` | {r['width']}×{r['height']} "
                     f"| {_pct(r.get('model_' + head))} | {_pct(r[head])} | "
                     f"{_pct(r.get('reference_' + head))} | "
                     f"{_ms(r['frame_ms'])} | {r['bake_s']:.0f} | "
                     f"{result['machine']['cpu']}, {result['finished'][:10]} |")
    return lines


def view_table(result: dict[str, Any]) -> list[str]:
    """engine.view's figures: per method, size, control and frame format, fps while
    dragging and the latency split (medians, ms), and the frame on release."""
    if result.get("skipped"):
        return [f"Not measured: {result['skipped']}."]
    lines = ["| method, scene | size | drag | format | fps | latency (p90) | render | encode "
             "| wait | transfer | paint | KiB | release: latency (render) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in result["results"]:
        for name, run in row["runs"].items():
            d, r = run["drag"], run.get("release") or {}
            control = name.partition("/")[0]
            lines.append(
                f"| {row['method']}, {row['scene']} | {row['size']}² | {control} | "
                f"{run['format']} | {d['fps']} | {_ms(d.get('latency_ms'))} "
                f"({_ms(d.get('latency_p90_ms'))}) | {_ms(d.get('render_ms'))} | "
                f"{_ms(d.get('encode_ms'))} | {_ms(d.get('queue_ms'))} | "
                f"{_ms(d.get('transfer_ms'))} | {_ms(d.get('paint_ms'))} | {d.get('kib')} | "
                f"{_ms(r.get('latency_ms'))} ({_ms(r.get('render_ms'))}) |")
    m = result["machine"]
    before = [r.get("load_before") or result["load_before"] for r in result["results"]]
    after = [r.get("load_after") or result.get("load_after", [0]) for r in result["results"]]
    if len(result.get("merged_from") or []) > 1:  # runs merged: each row's own loads
        lo, hi = min(x[0] for x in before), max(x[0] for x in before)
        load = (f"{len(result['merged_from'])} runs merged, load average {lo:.2f}–{hi:.2f} "
                f"before a row ({max(x[0] for x in after):.2f} at most after; per row in "
                "the result's JSON)")
    else:
        load = (f"load average {result['load_before'][0]:.2f} before, "
                f"{result.get('load_after', [0])[0]:.2f} after")
    lines += ["", f"Milliseconds, medians over the frames painted while a slider moved once "
              f"per animation frame for {result['seconds']:g} s (headless Chromium, "
              f"`python -m benchmarks run engine.view`); wait: the request's time queued "
              f"behind the render in flight. {m['cpu']}, OpenCL {m.get('opencl_device', '?')}, "
              f"{load}, {result['finished'][:10]}."]
    return lines


def _replace_block(path: Path, marker: str, lines: list[str]) -> bool:
    """Replace what follows ``marker`` in ``path`` up to the next heading or blank-line
    paragraph that is not a table with ``lines``; False if the marker is absent."""
    text = path.read_text() if path.is_file() else ""
    if marker not in text:
        return False
    start = text.index(marker)
    rest = text[start + len(marker):]
    # the generated block: blank lines, then table rows and a caption paragraph
    nxt = re.search(r"\n(?=#{1,6} |Which to use)", rest)
    end = start + len(marker) + (nxt.start() + 1 if nxt else len(rest))
    path.write_text(text[:start] + "\n".join([marker, "", *lines, ""]) + "\n" + text[end:])
    return True


def write_tables(results: Path) -> list[Path]:
    """Write docs/results.md and each method page's figures from ``results``; the
    paths written."""
    written: list[Path] = []
    measured: dict[str, dict[str, Any]] = {}
    out = ["# Results", "",
           "Generated by `python -m benchmarks table` from the JSON under "
           "`benchmarks/results/` (`python -m benchmarks run NAME` writes it); do not edit.",
           ""]
    sections = (("accuracy", "", MARKER, accuracy_table),
                ("suite", ": scene suite", SUITE_MARKER, suite_table))
    for name, title, marker, tabulate in sections:
        for m in METHODS:
            path = results / m / f"{name}.json"
            if not path.is_file():
                out += [f"## {m}{title}", "", f"Not measured: run `python -m benchmarks run "
                        f"{m}.{name}`.", ""]
                continue
            result = json.loads(path.read_text())
            table = tabulate(result)
            out += [f"## {m}{title}", "", *table, ""]
            if name == "accuracy":
                measured[m] = result
            page = DOCS / "methods" / f"{m}.md"
            if _replace_block(page, marker.format(m=m), table) and page not in written:
                written.append(page)
    view = results / "engine" / "view.json"
    if view.is_file():
        table = view_table(json.loads(view.read_text()))
        out += ["## prt view: latency while dragging", "", *table, ""]
        if _replace_block(DOCS / "view.md", VIEW_MARKER, table):
            written.append(DOCS / "view.md")
    others = sorted(p for p in results.rglob("*.json")
                    if p.parent.name in ("engine", *METHODS)
                    and p.name not in ("accuracy.json", "suite.json") and p != view)
    if others:
        out += ["## Other results", ""]
        out += [f"- `{p.relative_to(results)}`" for p in others]
        out.append("")
    target = DOCS / "results.md"
    target.write_text("\n".join(out))
    readme = DOCS.parent / "README.md"
    if measured and _replace_block(readme, README_MARKER, headline_rows(measured)):
        written.append(readme)
    return [target, *written]
