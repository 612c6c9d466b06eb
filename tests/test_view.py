"""``prt view`` (issue 43): the page in a real browser (headless Chromium driven by
Playwright, pointed at the system's Debian ``chromium``), for each method on its tiny
scene: a control moved in the page paints the bytes of ``prt render``'s PNG with the same
edits, and the save button writes the EXR ``prt render`` writes; a drag keeps one render
in flight; bad input is one error line or a message in the page; Ctrl-C stops the server
and leaves the work directory as it was. The state and edit tests need no browser."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import small_scene_dict, write_scene
from tiny_scenes import tiny_scene

from pipeline.errors import PrtError
from pipeline.images import read_exr
from pipeline.method import EDITS
from pipeline.registry import get_method, registry


def chromium() -> str | None:
    """The system Chromium (``$PRT_CHROMIUM``, else Debian's ``chromium``)."""
    for name in (os.environ.get("PRT_CHROMIUM"), "chromium", "chromium-browser"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def browser_missing() -> str | None:
    try:
        import playwright  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[test]')"
    if chromium() is None:
        return ("no system Chromium: install Debian's chromium and chromium-driver "
                "(apt-get install -y chromium chromium-driver; .ci/run does)")
    return None


needs_browser = pytest.mark.skipif(browser_missing() is not None,
                                   reason=browser_missing() or "")

# per method: the controls moved in the page (id -> value)
MOVES = {"d2i": {"light-0-x": 0.31, "mat-shiny-gamma": 700},
         "triple": {"environment": 90, "camera-azimuth": 25, "mat-shiny-gamma": 600},
         "sg": {"environment": 45, "camera-elevation": 10, "environment-scale": 1.5}}


def prt(*args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` but the lock: (size, mtime ns)."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in root.rglob("*") if p.is_file() and p.name != ".lock"}


class Viewer:
    """A ``prt view`` process on a free port."""

    def __init__(self, scene: Path, workdir: Path, save: Path, *extra: str,
                 env: dict[str, str] | None = None) -> None:
        self.workdir = workdir
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "pipeline", "view", str(scene), "--workdir", str(workdir),
             "--port", "0", "--save-dir", str(save), "-q", *extra],
            cwd=scene.parent, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env=None if env is None else {**os.environ, **env})
        deadline = time.time() + 300
        self.url = None
        while time.time() < deadline:
            line = self.proc.stdout.readline()
            if not line:
                break
            if "Viewing" in line:
                self.url = line.split(" at ")[1].split()[0]
                break
        if self.url is None:
            self.proc.kill()
            raise AssertionError(f"prt view did not start: {self.proc.stderr.read()}")
        self.before = snapshot(workdir)

    def stats(self) -> dict:
        import urllib.request

        with urllib.request.urlopen(self.url + "api/stats", timeout=30) as r:
            return json.loads(r.read())

    def stop(self) -> tuple[int, str]:
        """Ctrl-C: (exit status, its output)."""
        self.proc.send_signal(signal.SIGINT)
        out, err = self.proc.communicate(timeout=60)
        return self.proc.returncode, out + err


@pytest.fixture(scope="module")
def browser():
    reason = browser_missing()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        yield b
        b.close()


def wait_frame(page, after: int, timeout: float = 120_000) -> dict:
    """The header of the first frame painted, not while dragging, for a request after
    ``after`` (a request id)."""
    page.wait_for_function(
        f"window.prtView.lastPainted > {after} && !window.prtView.last.dragging",
        timeout=timeout)
    return page.evaluate("window.prtView.last")


def canvas_rgb(page) -> np.ndarray:
    data = page.evaluate("""() => { const c = document.getElementById('frame');
        return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data); }""")
    h, w = page.evaluate("[document.getElementById('frame').height, "
                         "document.getElementById('frame').width]")
    return np.array(data, np.uint8).reshape(h, w, 4)[..., :3]


@needs_browser
@pytest.mark.timeout(900)
@pytest.mark.parametrize("method", ["d2i", "triple", "sg"])
def test_page_frame_and_save_equal_prt_render(method, browser, tmp_path):
    """Controls moved in the page paint the PNG ``prt render`` writes for the command the
    page shows; the save button writes the EXR that command writes, bit for bit; the
    work directory is as it was after Ctrl-C."""
    from PIL import Image

    scene = tiny_scene(tmp_path, method, size=16).path
    viewer = Viewer(scene, tmp_path / "w", tmp_path / "saved")
    try:
        page = browser.new_page()
        page.goto(viewer.url)
        wait_frame(page, 0)
        page.select_option("#format", "png")  # lossless: the canvas holds the PNG's bytes
        last = page.evaluate("window.prtView.lastPainted")
        for control, value in MOVES[method].items():
            last = page.evaluate(f"window.prtView.set({control!r}, {value})")
        header = wait_frame(page, last - 1)
        assert header["format"] == "png" and header["mode"] == "frame"
        assert header["args"], "the moved controls are edits"
        if "environment-scale" in MOVES[method]:  # the map's scale: stops on the slider
            assert "--env-scale" in header["args"], header["args"]
        shown = canvas_rgb(page)
        page.click("#save")
        page.wait_for_function("window.prtView.saved", timeout=120_000)
        saved = page.evaluate("window.prtView.saved")
        assert "error" not in saved, saved
        page.close()
    finally:
        code, output = viewer.stop()
    assert code == 0 and "Stopped" in output, output
    assert snapshot(tmp_path / "w") == viewer.before  # the viewer only read it

    argv = shlex.split(header["command"])
    assert argv[:2] == ["prt", "render"] and argv[-2:] == ["--out", "view.exr"]
    done = prt(*argv[1:-1], tmp_path / "cli.exr", "-q", cwd=scene.parent)
    assert done.returncode == 0, done.stderr
    expected = np.asarray(Image.open(tmp_path / "cli.png").convert("RGB"))
    assert np.array_equal(shown, expected)
    edits = json.loads(Path(saved["edits_json"]).read_text())
    assert edits["args"] == header["args"]
    assert np.array_equal(read_exr(saved["exr"]), read_exr(tmp_path / "cli.exr"))
    # the saved JSON's command writes the same bytes again
    again = shlex.split(edits["command"])
    done = prt(*again[1:-1], tmp_path / "again.exr", "-q", cwd=scene.parent)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(read_exr(tmp_path / "again.exr"), read_exr(saved["exr"]))


@pytest.fixture(scope="module")
def d2i_viewer(tmp_path_factory):
    if browser_missing():
        pytest.skip(browser_missing())
    tmp = tmp_path_factory.mktemp("view_d2i")
    scene = tiny_scene(tmp, "d2i", size=16).path
    # a reference cached for the file's edits (the viewer finds it at start)
    done = prt("reference", scene, "--transport", "first-glossy", "--max-spp", 16,
               "--workdir", tmp / "w", "--out", tmp / "ref.exr", "-q", cwd=tmp)
    assert done.returncode == 0, done.stderr
    viewer = Viewer(scene, tmp / "w", tmp / "saved")
    yield viewer
    code, output = viewer.stop()
    assert code == 0, output


@needs_browser
@pytest.mark.timeout(600)
def test_drag_keeps_one_render_in_flight(d2i_viewer, browser):
    """A drag on the image sends a request per pointer move; the server never has more
    than one render in flight (newer requests replace the waiting one) and the page ends
    on the frame of the release."""
    page = browser.new_page()
    page.goto(d2i_viewer.url)
    wait_frame(page, 0)
    box = page.locator("#frame").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    for i in range(60):
        page.mouse.move(x + 2 * i, y - i)
    page.mouse.up()
    # a burst faster than any render: 40 slider moves sent back to back, then the release
    last = page.evaluate("""() => { const s = document.getElementById('light-0-z');
        for (let i = 1; i <= 40; i++) { s.value = -0.005 * i;
            s.dispatchEvent(new Event('input', {bubbles: true})); }
        s.dispatchEvent(new Event('change', {bubbles: true}));
        return window.prtView.request(false); }""")
    sent = page.evaluate("window.prtView.lastPainted")
    page.wait_for_function("window.prtView.last && !window.prtView.last.dragging && "
                           f"window.prtView.last.id >= {last}", timeout=120_000)
    stats = d2i_viewer.stats()
    assert stats["max_in_flight_viewer"] == 1 and stats["max_in_flight"] == 1
    assert stats["requests"] >= 100 and stats["rendered"] + stats["cache_hits"] + \
        stats["replaced"] + stats["errors"] <= stats["requests"] + 1
    assert stats["replaced"] > 0, stats  # the drag outran the renderer: requests dropped
    drag = [f for f in page.evaluate("window.prtView.painted") if f["dragging"]]
    assert drag and all(f["mode"] == "light" for f in drag)  # d2i's light-edit mode
    assert sent >= 1
    page.close()


@needs_browser
@pytest.mark.timeout(600)
def test_bad_edit_and_closed_tab(d2i_viewer, browser):
    """An edit out of its baked range is a message in the page; a tab closed while a
    render runs leaves the server serving the next page."""
    page = browser.new_page()
    page.goto(d2i_viewer.url)
    wait_frame(page, 0)
    page.evaluate("window.prtView.edits.materials.shiny.gamma = 5000; "
                  "window.prtView.request(false)")
    page.wait_for_function("window.prtView.errors.length > 0", timeout=120_000)
    message = page.inner_text("#error")
    assert message.startswith("error: ") and "outside the baked range [3, 300]" in message
    page.evaluate("window.prtView.set('light-0-z', -0.2)")
    page.close()  # while that frame renders
    again = browser.new_page()
    again.goto(d2i_viewer.url)
    assert wait_frame(again, 0)["width"] == 16
    again.close()


@needs_browser
@pytest.mark.timeout(600)
def test_cached_state_is_instant_and_reference_view(d2i_viewer, browser, tmp_path):
    """Returning to a state is answered from the render cache; the reference cached for
    the file's edits is shown beside the frame; for edits without one, the difference
    view says which command caches it."""
    page = browser.new_page()
    page.goto(d2i_viewer.url)
    assert wait_frame(page, 0)["reference"]
    page.select_option("#view", "side by side")
    page.wait_for_function("!document.getElementById('second').hidden", timeout=120_000)
    assert page.inner_text("#error") == ""
    page.select_option("#view", "frame")
    first = page.evaluate("window.prtView.set('mat-shiny-specular', 0.08)")
    assert not wait_frame(page, first - 1)["cached"]
    other = page.evaluate("window.prtView.set('mat-shiny-specular', 0.05)")
    wait_frame(page, other - 1)
    back = page.evaluate("window.prtView.set('mat-shiny-specular', 0.08)")
    header = wait_frame(page, back - 1)
    assert header["cached"] and header["render_ms"] == 0
    page.select_option("#view", "difference")
    page.wait_for_function("document.getElementById('error').textContent.length > 0",
                           timeout=120_000)
    assert "prt reference" in page.inner_text("#error")
    page.close()


@pytest.mark.timeout(600)
def test_open_opens_the_served_address(tmp_path):
    """``--open`` opens the printed address in the user's browser (Python's webbrowser,
    which runs ``$BROWSER`` with the address: here a script that records it), and the
    page is served there."""
    import urllib.request

    record = tmp_path / "opened.txt"
    browser = tmp_path / "browser.sh"
    browser.write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" >> {shlex.quote(str(record))}\n')
    browser.chmod(0o755)
    scene = tiny_scene(tmp_path, "sg", size=8).path
    viewer = Viewer(scene, tmp_path / "w", tmp_path / "saved", "--open",
                    env={"BROWSER": str(browser)})
    try:
        deadline = time.time() + 60
        while not record.is_file() and time.time() < deadline:
            time.sleep(0.1)
        opened = record.read_text().split()
        with urllib.request.urlopen(opened[0], timeout=30) as r:
            page = r.read().decode()
    finally:
        code, output = viewer.stop()
    assert code == 0, output
    assert opened == [viewer.url] and viewer.url.startswith("http://127.0.0.1:")
    assert "<title>prt view</title>" in page


def test_port_in_use_is_one_error_line(tmp_path):
    """A port in use: one ``error:`` line before anything is baked."""
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    port = taken.getsockname()[1]
    try:
        done = prt("view", "--port", port, "--workdir", tmp_path / "w", cwd=tmp_path,
                   timeout=120)
    finally:
        taken.close()
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"error: --port: port {port} is in use (another prt view or server); pick another "
        "with --port, or --port 0 for any free one"]
    assert not (tmp_path / "w").exists()


def test_scene_that_does_not_bake_is_one_error_line(tmp_path):
    doc = small_scene_dict(8)
    doc["methods"] = ["d2i"]
    del doc["materials"]["shiny"]["gamma_range"]
    scene = write_scene(tmp_path, doc)
    done = prt("view", scene, "--port", 0, "--workdir", tmp_path / "w", cwd=tmp_path,
               timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "gamma_range" in lines[0]


@pytest.mark.timeout(900)
@pytest.mark.parametrize("method", ["triple", "sg"])
def test_size_renders_from_the_files_bake(method, tmp_path):
    """A method that traces the camera at run time renders ``--size`` from the bake of
    the file's camera (decision 0045): ``prt render`` and ``prt view`` at 16² on the 8²
    bake re-bake nothing; where the bake depends on the camera (triple's atlas) a note
    says so, in the console and the page."""
    import urllib.request

    scene = tiny_scene(tmp_path, method, size=8).path
    work = tmp_path / "w"
    done = prt("render", scene, "--method", method, "--workdir", work, "--out",
               tmp_path / "a.exr", "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    before = snapshot(work)
    done = prt("render", scene, "--method", method, "--size", "16x16", "--workdir", work,
               "--out", tmp_path / "b.exr", "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert read_exr(tmp_path / "b.exr").shape == (16, 16, 3)
    assert snapshot(work) == before and not (work / "views").exists()
    note = "renders 16x16 from the triple.atlas, triple.visibility baked for the scene " \
        "file's 8x8 camera"
    assert (note in done.stderr) == (method == "triple"), done.stderr
    viewer = Viewer(scene, work, tmp_path / "saved", "--method", method, "--size", "16x16")
    try:
        with urllib.request.urlopen(viewer.url + "api/spec", timeout=30) as r:
            spec = json.loads(r.read())
    finally:
        code, output = viewer.stop()
    assert code == 0, output
    assert (spec["width"], spec["height"]) == (16, 16)
    assert any(note in n for n in spec["notices"]) == (method == "triple"), spec["notices"]
    assert (note in output) == (method == "triple")
    assert snapshot(work) == before and not (work / "views").exists()


def test_every_method_declares_known_edits():
    """The descriptors' run-time edits come from the core's vocabulary, and a drag's
    edit modes and options name the method's own edits and options."""
    for m in registry().values():
        assert set(m.edits) <= set(EDITS), m.name
        assert set(m.edit_modes) <= set(m.edits), m.name
        assert {n for n, _ in m.drag_options} <= {o.name for o in m.options}, m.name
    assert set(get_method("d2i").edits) == {"light", "gamma", "specular", "albedo"}
    assert {"environment", "camera"} <= set(get_method("triple").edits)
    assert set(get_method("sg").edits) == {"environment", "camera"}


def test_a_descriptor_s_option_reads_name_its_own_options_and_values():
    """``option_reads`` entries are checked when a plug-in registers: an option the
    method does not declare, or a value outside its choices, is one PrtError naming the
    plug-in's file; the built-in methods pass."""
    from dataclasses import replace

    from pipeline.registry import check_descriptor

    sg = get_method("sg")
    for m in registry().values():
        check_descriptor(m, "plugin.py")
    with pytest.raises(PrtError, match="plugin.py: method 'sg': option_reads names option "
                                       "'normals'"):
        check_descriptor(replace(sg, option_reads=(("normals", "vertex", ("sg.relax",)),)),
                         "plugin.py")
    with pytest.raises(PrtError, match="option_reads gives normal='vertx', not one of"):
        check_descriptor(replace(sg, option_reads=(("normal", "vertx", ("sg.relax",)),)),
                         "plugin.py")


def test_resolve_gives_prt_render_arguments(tmp_path):
    """A page's edits become ``prt render``'s arguments, applied by the command's own
    function; edits outside their range or not followed at run time are refused."""
    from pipeline.scene.edits import with_run_time_edits
    from pipeline.view.state import ViewScene

    scene = tiny_scene(tmp_path, "triple", size=8)
    view = ViewScene(scene, get_method("triple"), "scene.yaml", None, 4.0)
    r = view.resolve({"environment": 30, "camera": [10, 5], "options": {"budget": 80},
                      "environment_scale": 2.5,
                      "materials": {"shiny": {"gamma": 50, "specular": 0.05}}})
    camera = r.args[r.args.index("--camera") + 1]
    assert r.args == ("--set", "shiny.gamma=50.0", "--set", "shiny.specular=0.05",
                      "--camera", camera, "--env-rotate", "30.0", "--env-scale", "2.5",
                      "--option", "budget=80")
    again = with_run_time_edits(scene, ["shiny.gamma=50.0", "shiny.specular=0.05"], [],
                                camera, None, 30.0, 2.5)
    assert r.scene.environment.scale == 2.5
    assert again.document == r.scene.document and r.options["budget"] == 80
    assert np.isclose(np.linalg.norm(np.subtract(again.camera.position,
                                                 again.camera.look_at)), view.radius)
    assert view.resolve({"camera": [0, 0], "environment": 0,
                         "environment_scale": scene.environment.scale}).args == ()
    assert "view.exr" in view.command(r.args)
    for bad, words in (({"materials": {"shiny": {"gamma": 301}}}, "outside the baked"),
                       ({"lights": {"0": [1, 0, 0]}}, "does not move lights"),
                       ({"camera": [0, 90]}, "beyond"),
                       ({"options": {"budget": -1}}, ">= 0"),
                       ({"environment": "x"}, "expected a number"),
                       ({"environment_scale": -1}, "outside")):
        with pytest.raises(PrtError, match=words):
            view.resolve(bad)


def test_prt_render_move_light_and_camera_errors(tmp_path):
    """``prt render``'s new edits refuse bad input with one error line."""
    doc = small_scene_dict(8)
    doc["methods"] = ["direct"]
    scene = write_scene(tmp_path, doc)
    for args, words in ((("--move-light", "0=1,2"), "expected 3 finite numbers"),
                        (("--move-light", "7=0,0,0"), "no light 7"),
                        (("--move-light", "x"), "expected INDEX=DX,DY,DZ"),
                        (("--camera", "0,0.3,0"), "look_at"),
                        (("--env-scale", "-1"), "expected a finite number >= 0"),
                        (("--env-scale", "2"), "no environment light to scale")):
        done = prt("render", scene, "--out", tmp_path / "x.exr", *args, cwd=tmp_path,
                   timeout=120)
        assert done.returncode == 2, done.stderr
        assert done.stderr.startswith("error: ") and words in done.stderr, done.stderr


def test_tone_map_is_the_previews():
    """The viewer's 8-bit frames are the PNG previews' bytes."""
    from pipeline.images import srgb_encode
    from pipeline.view.encode import encode, tone_map

    rgb = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32) * 2
    for ev in (0.0, 1.3, -2.0):
        assert np.array_equal(tone_map(rgb, ev),
                              np.round(srgb_encode(rgb, 2 ** ev) * 255).astype(np.uint8))
    assert np.array_equal(np.frombuffer(encode(rgb, "f16"), np.float16).reshape(rgb.shape),
                          rgb.astype(np.float16))


def test_tone_map_table_is_the_curve_bit_for_bit():
    """The viewer's tone map by table (pipeline/view/encode.py ``tone_table``) gives the
    float64 curve's bytes: on each side of every step the table found, on every 4099th
    float32 bit pattern of every sign, and at zeros, infinities, denormals and the
    largest floats, at several exposures. (Every positive float32 below saturation was
    compared once, at three exposures: decision 0043's addendum.)"""
    from pipeline.view.encode import tone_map, tone_map_reference, tone_table

    special = np.array([0.0, -0.0, np.inf, -np.inf, 1e-45, -1e-45, 1.2e-38, 3.4e38,
                        -3.4e38, 0.0031308, 1.0, 0.5 / 255], np.float32)
    every = np.arange(0, 2**32, 4099, dtype=np.uint64).astype(np.uint32).view(np.float32)
    every = every[~np.isnan(every)]
    for ev in (0.0, 1.3, -2.0, 7.25):
        low, step = tone_table(ev)
        steps = step[step != 0xFFFFFFFF]
        assert 250 <= len(steps) <= 255  # one per 8-bit step that a positive float reaches
        near = np.concatenate([steps - 1, steps, steps + 1]).view(np.float32)
        for x in (special, near, every):
            with np.errstate(over="ignore", invalid="ignore"):
                assert np.array_equal(tone_map(x, ev), tone_map_reference(x, ev)), ev


def test_a_request_arriving_while_the_last_frame_is_sent_is_rendered():
    """The viewer's queue loses nothing: a request submitted while the previous frame is
    still being encoded and sent (the drain loop's last await) is rendered, not left
    waiting with no render to take it (no browser: a stand-in page and renderer)."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor
    from types import SimpleNamespace

    from pipeline.view.server import Stats, Viewer

    class Probe(Viewer):
        async def render(self, request):
            rendered.append(request["id"])
            return None, None, {}, 0.0

        async def send(self, request, *rest):
            if request["id"] == 1:
                self.submit({"id": 2})  # the user moves on while frame 1 goes out
            await asyncio.sleep(0)

    async def run() -> None:
        viewer = Probe(SimpleNamespace(stats=Stats()), SimpleNamespace(closed=False))
        viewer.submit({"id": 1})
        while viewer.busy or viewer.pending is not None:
            await asyncio.sleep(0.001)

    rendered: list[int] = []
    # on a thread of its own: Playwright's sync API (the browser fixture) keeps an event
    # loop running on this one
    with ThreadPoolExecutor(1) as pool:
        pool.submit(lambda: asyncio.run(asyncio.wait_for(run(), timeout=10))).result()
    assert rendered == [1, 2]
