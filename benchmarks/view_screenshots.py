"""The screenshots of docs/view.md: ``prt view`` on each method's default scene (baked in
the benchmark cache, benchmarks/fixtures.py), one edit made in the page as a user makes
it, the page captured by headless Chromium (the system's, through Playwright).

    python -m benchmarks.view_screenshots [--size 256] [--out docs/images]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from benchmarks.engine.view import (
    DEFAULT_SCENES,
    chromium,
    viewer_page,
    workdir_of,
)
from benchmarks.fixtures import ROOT

# per method: the controls moved (element id -> value), the image-drag target
EDITS = {"d2i": {"drag": 0, "moves": {}},           # a light dragged across the image
         "triple": {"drag": None, "moves": {"environment": 120}},
         "sg": {"drag": None, "moves": {"camera-azimuth": 35, "camera-elevation": 12}}}


def shoot(method: str, size: int, out: Path, browser) -> Path:
    scene_file = DEFAULT_SCENES[method]
    _, work = workdir_of(method, scene_file, size)
    with viewer_page(scene_file, size, work.root, browser, (1000, 760)) as page:
        last = 0
        for control, value in EDITS[method]["moves"].items():
            last = page.evaluate(f"window.prtView.set({control!r}, {value})")
        if EDITS[method]["drag"] is not None:
            box = page.locator("#frame").bounding_box()
            x, y = box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.45
            page.mouse.move(x, y)
            page.mouse.down()
            for i in range(30):
                page.mouse.move(x + 3 * i, y)
            page.mouse.up()
            last = page.evaluate("window.prtView.request(false)")
        page.wait_for_function(f"window.prtView.lastPainted >= {last} && "
                               "!window.prtView.last.dragging", timeout=600_000)
        target = out / f"view_{method}.png"
        page.screenshot(path=str(target))
    return target


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.view_screenshots")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--methods", default="d2i,triple,sg")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    args.out.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        for method in args.methods.split(","):
            print(shoot(method, args.size, args.out, browser), flush=True)
        browser.close()


if __name__ == "__main__":
    main()
