"""prt view end to end: latency (input to paint) and fps while dragging, split in parts.

Latency is from the input event to the frame painted, split into render, encode,
transfer and paint; fps is sustained while dragging.

For each method (``--methods``; its default scene: d2i the Cornell box, triple
bunny_grace, sg bunny_sg) at each size (``--sizes``): the scene is baked once (the
benchmark cache, benchmarks/fixtures.py ``baked``), ``prt view`` is started on it as a
user starts it, and headless Chromium (the system's, through Playwright) drags a
control for ``--seconds``: a slider moved once per animation frame (the browser's
display rate, ~60 Hz), as a user's drag sends it. The control is the method's headline
run-time edit (``--controls``): the environment's turn where the method turns it
(triple, sg), else a glossy material's γ (d2i's BRDF edit), and, for a method that moves
lights, a light (d2i's light edit). Measured in the page (pipeline/view/static/app.js):
per painted frame, the server's render and encode times, the transfer (the round trip
less the server's time) and the paint (decode and draw); the latency from the input
event that the frame answers to its paint; fps = frames painted during the drag / its
length. And the frame on release (the accurate one). At the largest size each frame
format (``--formats``: JPEG, WebP, PNG, float16 tone-mapped in the page) is measured on
the headline control (decision 0043 chose the default from it).

Run from the project root: python -m benchmarks run engine.view [--tiny] [-- --methods
d2i,triple,sg --sizes 256,512 --seconds 6]. Needs Playwright and the system Chromium
(Debian ``chromium``); without them the result says so and measures nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.fixtures import CACHE, SCENES, TINY, baked, load, write_result

PRESETS = {"default": [],
           "tiny": ["--scenes", f"d2i={TINY / 'tiny_d2i.yaml'}", "--methods", "d2i",
                    "--sizes", "16", "--seconds", "1", "--formats", "jpeg,f16"]}
DEFAULT_SCENES = {"d2i": SCENES / "cornell_box.yaml", "triple": SCENES / "bunny_grace.yaml",
                  "sg": SCENES / "bunny_sg.yaml"}
SPLIT = ("render_ms", "encode_ms", "queue_ms", "transfer_ms", "paint_ms", "latency_ms")

# one slider moved per animation frame for `seconds`, then released; the painted frames'
# measurements from then on
DRAG = """async ([id, seconds, lo, hi]) => {
  const s = document.getElementById(id);
  const first = window.prtView.painted.length;
  const start = performance.now();
  let i = 0;
  await new Promise((done) => {
    const step = () => {
      const t = performance.now() - start;
      if (t > seconds * 1000) { done(); return; }
      i += 1;
      s.value = lo + (hi - lo) * ((i * 0.618034) % 1);   // a new value every frame
      s.dispatchEvent(new Event('input', {bubbles: true}));
      requestAnimationFrame(step);
    };
    requestAnimationFrame(step);
  });
  const end = performance.now();
  s.dispatchEvent(new Event('change', {bubbles: true}));
  return {first, start, end, inputs: i};
}"""


def chromium() -> str | None:
    for name in (os.environ.get("PRT_CHROMIUM"), "chromium", "chromium-browser"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def start_viewer(scene: Path, size: int, workdir: Path, save: Path) -> tuple[Any, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "pipeline", "view", str(scene), "--size", f"{size}x{size}",
         "--workdir", str(workdir), "--port", "0", "--save-dir", str(save), "-q"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 3600
    while time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if "Viewing" in line:
            return proc, line.split(" at ")[1].split()[0]
    proc.kill()
    raise RuntimeError(f"prt view did not start: {proc.stderr.read()[-2000:]}")


def stop_viewer(proc) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()


@contextlib.contextmanager
def viewer_page(scene_file: Path, size: int, workdir: Path, browser: Any,
                viewport: tuple[int, int]) -> Iterator[Any]:
    """A browser page (``viewport`` width, height in CSS pixels) of ``prt view`` on the
    scene at ``size``² baked in ``workdir``, once its first frame is painted; the page
    closed and the viewer stopped (Ctrl-C) after."""
    with tempfile.TemporaryDirectory() as save:
        proc, url = start_viewer(scene_file, size, workdir, Path(save))
        try:
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            page.goto(url)
            page.wait_for_function("window.prtView && window.prtView.lastPainted > 0",
                                   timeout=600_000)
            yield page
            page.close()
        finally:
            stop_viewer(proc)


def controls_of(spec: dict[str, Any], wanted: list[str]) -> dict[str, tuple[str, float, float]]:
    """control name -> (element id, low, high) of the page's sliders, for ``wanted``."""
    found: dict[str, tuple[str, float, float]] = {}
    glossy = [m for m in spec["materials"] if "gamma" in m["keys"]]
    for name in wanted:
        if name == "environment" and spec["environment"]:
            found[name] = ("environment", -180.0, 180.0)
        elif name == "gamma" and glossy:
            found[name] = (f"mat-{glossy[0]['name']}-gamma", 0.0, 1000.0)
        elif name == "light" and spec["lights"]:
            found[name] = (f"light-{spec['lights'][0]['index']}-x", -spec["reach"],
                           spec["reach"])
    return found


def summary(frames: list[dict[str, Any]], seconds: float) -> dict[str, Any]:
    out: dict[str, Any] = {"frames": len(frames),
                           "fps": round(len(frames) / seconds, 2) if seconds else None}
    for key in SPLIT:
        values = [f[key] for f in frames if f.get(key) is not None]
        if values:
            out[key] = round(float(np.median(values)), 2)
            out[key.replace("_ms", "_p90_ms")] = round(float(np.percentile(values, 90)), 2)
    out["kib"] = round(float(np.median([f["bytes"] for f in frames])) / 1024, 1) \
        if frames else None
    return out


def drag(page, control: tuple[str, float, float], seconds: float, fmt: str
         ) -> dict[str, Any]:
    page.select_option("#format", fmt)
    page.wait_for_function(f"window.prtView.last && window.prtView.last.format === {fmt!r}",
                           timeout=600_000)
    info = page.evaluate(DRAG, [control[0], seconds, control[1], control[2]])
    page.wait_for_function("window.prtView.last && !window.prtView.last.dragging",
                           timeout=600_000)
    painted = page.evaluate("window.prtView.painted")[info["first"]:]
    during = [f for f in painted if f["dragging"] and f["t"] <= info["end"] + 1e-3]
    release = [f for f in painted if not f["dragging"]]
    return {"format": fmt, "inputs": info["inputs"],
            "drag": summary(during, (info["end"] - info["start"]) / 1e3),
            "release": summary(release[-1:], 0.0) if release else None}


def workdir_of(method: str, scene_file: Path, size: int) -> tuple[Any, Any]:
    """The scene at ``size``² and the work directory ``prt view --size`` renders it from,
    baked there (the benchmark cache's folder of the file's own size,
    benchmarks/fixtures.py ``baked``): for a method that traces the camera at run time
    (triple, sg) the file's bake itself (pipeline/job.py ``bake_scene``, decision 0045),
    for another its camera-dependent artifacts apart (``views/WxH``), the rest shared."""
    from pipeline import job
    from pipeline.engine.keys import digest
    from pipeline.registry import get_method

    opened = job.open_scene(scene_file)
    cam = opened.camera
    folder = CACHE / f"{opened.name}_{cam.width}x{cam.height}_{digest({})[:8]}"
    scene = opened.with_image_size(size, size)
    bake_scene = job.bake_scene(get_method(method), scene, opened)
    _, work = baked(bake_scene, workdir=folder)
    return scene, work


def measure(method: str, scene_file: Path, size: int, wanted: list[str], formats: list[str],
            seconds: float, browser) -> dict[str, Any]:
    t0 = time.perf_counter()
    scene, work = workdir_of(method, scene_file, size)
    bake_s = time.perf_counter() - t0
    load_before = load()
    with viewer_page(scene_file, size, work.root, browser, (1400, 1000)) as page:
        spec = page.evaluate("fetch('/api/spec').then(r => r.json())")
        runs = {}
        for name, control in controls_of(spec, wanted).items():
            for fmt in formats if name == next(iter(controls_of(spec, wanted))) \
                    else formats[:1]:
                runs[f"{name}/{fmt}"] = drag(page, control, seconds, fmt)
        stats = page.evaluate("fetch('/api/stats').then(r => r.json())")
    return {"method": method, "scene": scene.name, "size": size, "bake_s": round(bake_s, 1),
            "runs": runs, "server": stats, "load_before": load_before, "load_after": load()}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(prog="python -m benchmarks run engine.view --")
    parser.add_argument("--methods", default="d2i,triple,sg")
    parser.add_argument("--scenes", action="append", default=[], metavar="METHOD=FILE")
    parser.add_argument("--sizes", default="256,512")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--controls", default="environment,gamma,light")
    parser.add_argument("--formats", default="jpeg,webp,png,f16",
                        help="every format at the largest size; the first at the others")
    parser.add_argument("--merge", type=Path, default=None, metavar="JSON",
                        help="an earlier result whose rows this run's (method, size) do "
                             "not replace are kept (merged_from lists the runs)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    scenes = DEFAULT_SCENES | {k: Path(v) for k, v in (s.split("=", 1) for s in args.scenes)}
    sizes = [int(s) for s in args.sizes.split(",")]
    formats = args.formats.split(",")
    result: dict[str, Any] = {"seconds": args.seconds, "load_before": load(),
                              "cache": str(CACHE), "results": []}
    missing = None
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        missing = "playwright is not installed"
    if missing is None and chromium() is None:
        missing = "no system Chromium (apt-get install -y chromium chromium-driver)"
    if missing:
        result["skipped"] = missing
        return write_result("engine.view", result, args.out)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        for method in args.methods.split(","):
            for size in sizes:
                row = measure(method, scenes[method], size, args.controls.split(","),
                              formats if size == max(sizes) else formats[:1],
                              args.seconds, browser)
                result["results"].append(row)
                for name, run in row["runs"].items():
                    d = run["drag"]
                    print(f"{method} {size}² {name}: {d['fps']} fps, latency "
                          f"{d.get('latency_ms')} ms (render {d.get('render_ms')}, encode "
                          f"{d.get('encode_ms')}, queue {d.get('queue_ms')}, transfer "
                          f"{d.get('transfer_ms')}, paint {d.get('paint_ms')})", flush=True)
        browser.close()
    result["load_after"] = load()
    if args.merge is not None:
        result = merged(json.loads(args.merge.read_text()), result,
                        f"engine.view -- --methods {args.methods} --sizes {args.sizes} "
                        f"--controls {args.controls} --formats {args.formats} "
                        f"--seconds {args.seconds:g}")
    return write_result("engine.view", result, args.out)


def merged(old: dict[str, Any], new: dict[str, Any], run: str) -> dict[str, Any]:
    """``new``'s rows and ``old``'s rows of other (method, size), by method (in the
    order they first appear) and size; each row keeps its own load averages (an old row
    without them gets its run's)."""
    mine = {(r["method"], r["size"]): r for r in new["results"]}
    rows = []
    for row in old["results"]:
        key = (row["method"], row["size"])
        if key in mine:
            rows.append(mine.pop(key))
        else:
            rows.append({"load_before": old.get("load_before"),
                         "load_after": old.get("load_after"), **row})
    rows += list(mine.values())
    order = list(dict.fromkeys(r["method"] for r in rows))  # each method's rows together
    rows.sort(key=lambda r: (order.index(r["method"]), r["size"]))
    runs = old.get("merged_from") or ["earlier run"]
    return {**new, "results": rows, "merged_from": [*runs, run]}
