"""``prt view``: relight a baked scene interactively in the browser (issue 43).

state.py turns a page's edits into ``prt render``'s arguments and the edited scene
(through pipeline/scene/edits.py, the command's own path); encode.py tone-maps and
compresses frames; server.py serves the page (static/, built from the method's
descriptor: its ``edits``, ``options``, ``drag_options``, ``edit_modes``), renders off
the event loop, one render in flight per viewer, newest request wins. No method is named
here: a plug-in's edits and options appear in the page by themselves.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
from collections.abc import Callable
from pathlib import Path

from pipeline.errors import PrtError


def bind(port: int, host: str = "127.0.0.1") -> socket.socket:
    """A listening socket on ``host:port`` (0: any free port), or PrtError naming the
    port when it is in use, before anything is baked."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind((host, port))
        sock.listen(64)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise PrtError("--port", f"port {port} is in use (another prt view or server); "
                           "pick another with --port, or --port 0 for any free one") from None
        raise PrtError("--port", f"cannot listen on {host}:{port} ({exc.strerror})") from None
    return sock


def serve(engine, sock: socket.socket, save_dir: Path,
          ready: Callable[[str], None] | None = None) -> None:
    """Serve the viewer on ``sock`` until Ctrl-C (or SIGTERM); ``ready(url)`` is called
    once it listens. Stops cleanly: the socket closed, the render thread joined."""
    import signal

    from aiohttp import web

    from pipeline.view.server import make_app

    async def main() -> None:
        runner = web.AppRunner(make_app(engine, save_dir), handle_signals=False,
                               shutdown_timeout=1.0)
        await runner.setup()
        site = web.SockSite(runner, sock, shutdown_timeout=1.0)
        await site.start()
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, stop.set)
        host, port = sock.getsockname()[:2]
        if ready is not None:
            ready(f"http://{host}:{port}/")
        try:
            await stop.wait()
        finally:
            await runner.cleanup()

    try:
        asyncio.run(main())
    finally:
        engine.executor.shutdown(wait=True, cancel_futures=True)
        sock.close()
