"""``prt view``'s server (aiohttp, decision 0043): the page, a WebSocket per viewer for
frames, and HTTP calls to save a frame and fetch the cached reference.

Latency first. Renders run on one thread off the event loop (a renderer is not
thread-safe; OpenCL queues and its caches are its own). Each viewer has at most one
render in flight and one request waiting: a newer request replaces the waiting one, so a
drag never builds a backlog (:class:`Viewer`; the counts are at ``/api/stats``). Frames
are kept by their ``prt render`` arguments (:class:`Engine`, a render cache), so
returning to a state costs only the encoding. While the user drags, a method's
``drag_options`` and ``edit_modes`` (pipeline/method.py) give a cheaper frame; on
release the page asks for the frame ``prt render`` renders.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from aiohttp import WSMsgType, web

from pipeline.engine.store import Workdir, open_artifact, read_record
from pipeline.errors import PrtError
from pipeline.render import Frame, Renderer
from pipeline.view.encode import DEFAULT_FORMAT, FORMATS, difference, encode
from pipeline.view.state import Resolved, ViewScene, number

FRAME_CACHE = 48  # frames kept (a 512² frame: 3 MB)
RENDERERS = 2  # renderers kept, by options (the release's and a drag's budget)
# the ``prt render`` arguments of each edit group (an edit mode's base leaves its own out)
GROUP_FLAGS = {"light": ("--move-light",), "gamma": ("--set",), "specular": ("--set",),
               "albedo": ("--set",), "camera": ("--camera",),
               "environment": ("--env-rotate", "--env-scale")}


@dataclass
class Stats:
    """What the server measured: renders requested, rendered, answered from the cache,
    replaced while waiting (never rendered), and the most renders in flight at once for
    one viewer and over all viewers."""

    requests: int = 0
    rendered: int = 0
    cache_hits: int = 0
    replaced: int = 0
    errors: int = 0
    in_flight: int = 0
    max_in_flight: int = 0
    max_in_flight_viewer: int = 0
    viewers: int = 0
    render_ms: list[float] = field(default_factory=list)


class Engine:
    """The renders of every viewer of one scene and method, on one thread."""

    def __init__(self, view: ViewScene, workdir: Workdir) -> None:
        self.view, self.workdir = view, workdir
        self.executor = ThreadPoolExecutor(1, thread_name_prefix="prt-view-render")
        self.renderers: OrderedDict[str, Renderer] = OrderedDict()
        self.frames: OrderedDict[str, tuple[np.ndarray, dict[str, float]]] = OrderedDict()
        self.mode: tuple[str, Any] | None = None  # (key, frame function) of an edit mode
        self.stats = Stats()
        self.exposure = 0.0  # the page's exposure at start (EV)
        self.notices: list[str] = []  # prt view's note: and warning: lines, for the page
        self.references = self._cached_references()
        self.lock = threading.Lock()

    # renderers and frames (on the render thread) --------------------------------
    def renderer(self, options: dict[str, Any]) -> Renderer:
        from pipeline import job

        key = json.dumps(options, sort_keys=True, default=str)
        if key not in self.renderers:
            if len(self.renderers) >= RENDERERS:
                self.renderers.popitem(last=False)
                self.mode = None
            self.renderers[key] = job.frame_renderer(self.view.scene, self.workdir,
                                                     self.view.method.name, options)
        self.renderers.move_to_end(key)
        return self.renderers[key]

    def frame(self, edits: dict[str, Any], dragging: bool = False,
              control: str | None = None) -> tuple[Resolved, np.ndarray, dict[str, Any]]:
        """The frame of a page's ``edits`` (cached), and what it cost; while
        ``dragging`` ``control`` (an edit group), in the method's cheaper setting."""
        m = self.view.method
        extra = dict(m.drag_options) if dragging else None
        resolved = self.view.resolve(edits, extra)
        kind = m.edit_modes.get(control) if dragging and control else None
        key = json.dumps([resolved.key, resolved.options, kind], default=str)
        info: dict[str, Any] = {"mode": kind or "frame", "cached": key in self.frames}
        with self.lock:
            if key in self.frames:
                self.frames.move_to_end(key)
                rgb, timings = self.frames[key]
                self.stats.cache_hits += 1
                return resolved, rgb, {**info, "render_ms": 0.0, **timings}
            t0 = time.perf_counter()
            renderer = self.renderer(resolved.options)
            if kind is not None:
                frame = self._mode_frame(renderer, kind, resolved)
            else:
                self.mode = None  # a full frame leaves the renderer's state as its own
                frame = renderer.frame(resolved.scene)
            ms = (time.perf_counter() - t0) * 1e3
            bad = int(frame.rgb.size - np.isfinite(frame.rgb).sum())
            if bad:
                raise PrtError(m.name, f"the frame has {bad} NaN or Inf values")
            timings = {"kernel_ms": float(frame.timings.get("kernel_ms", 0.0))}
            self.frames[key] = (frame.rgb, timings)
            if len(self.frames) > FRAME_CACHE:
                self.frames.popitem(last=False)
            self.stats.rendered += 1
            self.stats.render_ms.append(ms)
            del self.stats.render_ms[:-1000]
        return resolved, frame.rgb, {**info, "render_ms": ms, **timings}

    def _mode_frame(self, renderer: Renderer, kind: str, resolved: Resolved) -> Frame:
        """A frame in the renderer's ``kind`` edit mode, entered at the first frame of a
        drag whose other edits are these (a new base enters it again)."""
        flags = {f for g, k in self.view.method.edit_modes.items() if k == kind
                 for f in GROUP_FLAGS[g]}
        args, base = list(resolved.args), []
        for i in range(0, len(args), 2):
            if args[i] not in flags:
                base += args[i:i + 2]
        key = json.dumps([id(renderer), kind, base])
        if self.mode is None or self.mode[0] != key:
            self.mode = (key, renderer.edit_mode(kind, resolved.scene))
        return self.mode[1](resolved.scene)

    def save(self, edits: dict[str, Any], exposure: float, folder: Path) -> dict[str, Any]:
        """The frame of ``edits`` written as ``prt render`` writes it (pipeline/job.py
        ``render``: EXR, PNG × 2^exposure, its record) and a JSON of its edits and the
        command that renders the same bytes."""
        from pipeline import job

        resolved = self.view.resolve(edits)
        folder.mkdir(parents=True, exist_ok=True)
        stem = f"{self.view.scene.name}_{self.view.method.name}_view"
        n = 1 + max((int(p.stem.rsplit("_", 1)[1]) for p in folder.glob(f"{stem}_*.exr")
                     if p.stem.rsplit("_", 1)[1].isdigit()), default=0)
        out = folder / f"{stem}_{n:04d}.exr"
        with self.lock:
            renderer = self.renderer(resolved.options)
            self.mode = None
            job.render(resolved.scene, self.workdir, self.view.method.name, out,
                       quiet=True, options=resolved.options, exposure=exposure,
                       renderer_of=lambda: renderer, baked=[])
        command = self.view.command(resolved.args, str(out), exposure)
        record = {"scene": self.view.scene_arg, "method": self.view.method.name,
                  "size": self.view.size, "edits": edits, "exposure": exposure,
                  "args": list(resolved.args), "command": command,
                  "exr": str(out), "png": str(out.with_suffix(".png"))}
        edits_json = out.with_name(f"{out.stem}_edits.json")
        edits_json.write_text(json.dumps(record, indent=1))
        return {**record, "edits_json": str(edits_json)}

    # references (only read: prt reference and prt evaluate cache them) ----------
    def _cached_references(self) -> list[tuple[str, Path]]:
        """(scene sections as JSON, path) of each cached reference of the method's
        transport, whole BRDF, under the work directory's ``reference/``."""
        found = []
        folder = self.workdir.root / "reference"
        for path in sorted(folder.glob("*.zarr")) if folder.is_dir() else []:
            try:
                record = read_record(path) or {}
            except PrtError:
                continue
            parts = record.get("key_parts", {})
            settings = parts.get("settings", {})
            if settings.get("transport") == self.view.method.reference and \
                    settings.get("lobe", "all") == "all":
                found.append((json.dumps(parts.get("scene"), sort_keys=True), path))
        return found

    def reference_of(self, resolved: Resolved) -> Path | None:
        sections = {s: resolved.scene.section(s) for s in ("camera", "lights", "materials")}
        mine = json.dumps(json.loads(json.dumps(sections, default=list)), sort_keys=True)
        return next((p for s, p in self.references if s == mine), None)


class Viewer:
    """One page's WebSocket: at most one render in flight, the newest request waiting."""

    def __init__(self, engine: Engine, ws: web.WebSocketResponse) -> None:
        self.engine, self.ws = engine, ws
        self.pending: dict[str, Any] | None = None
        self.busy = False
        self.in_flight = 0

    def submit(self, request: dict[str, Any]) -> None:
        self.engine.stats.requests += 1
        if self.pending is not None:
            self.engine.stats.replaced += 1
        request["received"] = time.perf_counter()
        self.pending = request
        if not self.busy:
            self.busy = True
            asyncio.get_running_loop().create_task(self.drain())

    async def drain(self) -> None:
        """Render the waiting request while the previous frame is encoded and sent: at
        most one render and one encoding per viewer at a time (no backlog of either),
        the frames sent in the order rendered."""
        sending: asyncio.Task | None = None
        try:
            while not self.ws.closed:
                if self.pending is None:
                    if sending is None:
                        break  # no await from here to ``busy = False``: nothing is lost
                    await sending  # a request may arrive meanwhile: the loop takes it
                    sending = None
                    continue
                request, self.pending = self.pending, None
                rendered = await self.render(request)
                if sending is not None:
                    await sending
                sending = None if rendered is None else \
                    asyncio.get_running_loop().create_task(self.send(request, *rendered))
            if sending is not None:
                await sending
        finally:
            self.busy = False

    async def render(self, request: dict[str, Any]) -> tuple | None:
        """The request's frame (resolved edits, linear RGB, what it cost, when its render
        started), or None when an error was sent instead."""
        engine, stats, loop = self.engine, self.engine.stats, asyncio.get_running_loop()
        start = time.perf_counter()
        self.in_flight += 1
        stats.in_flight += 1
        stats.max_in_flight_viewer = max(stats.max_in_flight_viewer, self.in_flight)
        stats.max_in_flight = max(stats.max_in_flight, stats.in_flight)
        try:
            if (request.get("format") or DEFAULT_FORMAT) not in FORMATS:
                raise PrtError("format", f"unknown frame format {request.get('format')!r}")
            exposure = number(request.get("exposure") or 0.0, "exposure")
            if not -64 <= exposure <= 64:
                raise PrtError("exposure", f"{exposure!r}: expected stops between -64 and 64")
            resolved, rgb, info = await loop.run_in_executor(
                engine.executor, engine.frame, request.get("edits") or {},
                bool(request.get("dragging")), request.get("control"))
        except PrtError as exc:
            await self.error(request, f"error: {exc.one_line()}")
            return None
        except Exception as exc:  # a renderer's failure: shown, the server goes on
            await self.error(request, f"error: {type(exc).__name__}: {exc}")
            return None
        finally:
            self.in_flight -= 1
            stats.in_flight -= 1
        return resolved, rgb, info, start

    async def send(self, request: dict[str, Any], resolved: Resolved, rgb: np.ndarray,
                   info: dict[str, Any], start: float) -> None:
        engine, loop = self.engine, asyncio.get_running_loop()
        fmt = request.get("format") or DEFAULT_FORMAT
        exposure = float(request.get("exposure") or 0.0)
        t1 = time.perf_counter()
        try:
            payload = await loop.run_in_executor(None, encode, rgb, fmt, exposure)
        except Exception as exc:  # noqa: BLE001 - shown in the page, the server goes on
            await self.error(request, f"error: cannot encode the frame ({exc})")
            return
        encode_ms = (time.perf_counter() - t1) * 1e3
        header = {"type": "frame", "id": request.get("id"), "format": fmt,
                  "width": int(rgb.shape[1]), "height": int(rgb.shape[0]),
                  "dragging": bool(request.get("dragging")), **info,
                  "encode_ms": encode_ms,
                  "queue_ms": (start - request["received"]) * 1e3,
                  "server_ms": (time.perf_counter() - request["received"]) * 1e3,
                  "bytes": len(payload), "args": list(resolved.args),
                  "command": engine.view.command(resolved.args, "view.exr", exposure),
                  "reference": engine.reference_of(resolved) is not None}
        head = json.dumps(header).encode()
        if not self.ws.closed:
            with contextlib.suppress(ConnectionError, RuntimeError):
                await self.ws.send_bytes(struct.pack("<I", len(head)) + head + payload)

    async def error(self, request: dict[str, Any], message: str) -> None:
        self.engine.stats.errors += 1
        await self._send_json({"type": "error", "id": request.get("id"), "message": message})

    async def _send_json(self, body: dict[str, Any]) -> None:
        if not self.ws.closed:
            with contextlib.suppress(ConnectionError, RuntimeError):
                await self.ws.send_str(json.dumps(body))


def static_text(name: str) -> str:
    return resources.files("pipeline.view").joinpath("static", name).read_text("utf-8")


def make_app(engine: Engine, save_dir: Path) -> web.Application:
    """The viewer's routes."""
    app = web.Application(client_max_size=1 << 20)

    async def index(_: web.Request) -> web.Response:
        return web.Response(text=static_text("index.html"), content_type="text/html")

    async def script(_: web.Request) -> web.Response:
        return web.Response(text=static_text("app.js"),
                            content_type="application/javascript")

    async def spec(_: web.Request) -> web.Response:
        body = engine.view.spec() | {"formats": list(FORMATS), "format": DEFAULT_FORMAT,
                                     "reference_transport": engine.view.method.reference,
                                     "exposure": engine.exposure,
                                     "notices": engine.notices,
                                     "save_dir": str(save_dir)}
        return web.json_response(body)

    async def stats(_: web.Request) -> web.Response:
        s = engine.stats
        ms = sorted(s.render_ms)
        return web.json_response({**{k: v for k, v in vars(s).items() if k != "render_ms"},
                                  "median_render_ms": ms[len(ms) // 2] if ms else None})

    async def websocket(request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=20, max_msg_size=1 << 20)
        await ws.prepare(request)
        viewer = Viewer(engine, ws)
        engine.stats.viewers += 1
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    body = json.loads(msg.data)
                except ValueError:
                    await viewer._send_json({"type": "error", "message":
                                             "error: the page sent a message that is not JSON"})
                    continue
                if isinstance(body, dict) and body.get("type") == "frame":
                    viewer.submit(body)
        finally:
            viewer.pending = None  # a closed tab: nothing more is rendered for it
            engine.stats.viewers -= 1
        return ws

    async def post_json(request: web.Request) -> dict[str, Any]:
        try:
            body = await request.json()
        except ValueError:
            raise PrtError("request", "expected a JSON body") from None
        if not isinstance(body, dict):
            raise PrtError("request", "expected a JSON object")
        return body

    async def save(request: web.Request) -> web.Response:
        loop = asyncio.get_running_loop()
        try:
            body = await post_json(request)
            exposure = float(body.get("exposure") or 0.0)
            result = await loop.run_in_executor(engine.executor, engine.save,
                                                body.get("edits") or {}, exposure, save_dir)
        except PrtError as exc:
            return web.json_response({"error": f"error: {exc.one_line()}"}, status=400)
        return web.json_response(result)

    async def reference(request: web.Request) -> web.Response:
        loop = asyncio.get_running_loop()
        try:
            body = await post_json(request)
            exposure = float(body.get("exposure") or 0.0)
            resolved, rgb, _ = await loop.run_in_executor(engine.executor, engine.frame,
                                                          body.get("edits") or {})
            path = engine.reference_of(resolved)
            if path is None:
                raise PrtError("reference", "no reference is cached for these edits: "
                               f"{reference_command(engine, resolved)}")
            ref = await loop.run_in_executor(None, lambda: open_artifact(path, "reference")
                                             .read("mean"))
            image = difference(rgb, ref) if body.get("view") == "difference" else ref
            payload = await loop.run_in_executor(None, encode, image, "png",
                                                 0.0 if body.get("view") == "difference"
                                                 else exposure)
        except PrtError as exc:
            return web.json_response({"error": f"error: {exc.one_line()}"}, status=404)
        return web.Response(body=payload, content_type="image/png")

    async def favicon(_: web.Request) -> web.Response:
        return web.Response(status=204)

    app.router.add_get("/", index)
    app.router.add_get("/favicon.ico", favicon)
    app.router.add_get("/app.js", script)
    app.router.add_get("/api/spec", spec)
    app.router.add_get("/api/stats", stats)
    app.router.add_get("/ws", websocket)
    app.router.add_post("/api/save", save)
    app.router.add_post("/api/reference", reference)
    return app


def reference_command(engine: Engine, resolved: Resolved) -> str:
    """The ``prt reference`` command that caches the reference the page compares with
    (material edits only: prt reference takes no other)."""
    import shlex

    view = engine.view
    argv = ["prt", "reference", *([view.scene_arg] if view.scene_arg else []),
            "--transport", view.method.reference]
    if view.size:
        argv += ["--size", view.size]
    if view.workdir_arg:
        argv += ["--workdir", view.workdir_arg]
    sets = [resolved.args[i + 1] for i in range(0, len(resolved.args), 2)
            if resolved.args[i] == "--set"]
    others = [resolved.args[i] for i in range(0, len(resolved.args), 2)
              if resolved.args[i] not in ("--set", "--option")]
    if others:
        return "prt reference renders the scene file's lights and camera; reset " \
               f"{', '.join(sorted(set(others)))} to compare"
    argv += [a for s in sets for a in ("--set", s)]
    return shlex.join([*argv, "--out", "reference.exr"])
