"""The viewer's web server: the page, its static files, and one websocket per open page.

Protocol (JSON text messages):

page -> server
    {"type": "set", "settings": {"sun_azimuth": 30.0, ...}}   change some controls
    {"type": "set", "settings": {"frame": 12}}                  a sequence's frame
    {"type": "save"}                                            save the full view (PNG + TOML)
server -> page
    {"type": "init", "settings": {...}, "ranges": {...}, "frames": {...} | null, "follows": [...], ...}
    {"type": "frame", "png": base64, "level": "draft"|"preview"|"full", "version": n, "frame": n | null,
     "follows": [...], "seconds": {...}, ...}
    {"type": "saved", "png": path, "toml": path}
    {"type": "error", "message": "..."}                        a bad message; the server goes on

Latest request wins: each page has one pending-request slot, overwritten by every "set"; one
worker thread (shared by all pages) renders. While messages arrive, frames are drafts; once
none has arrived for ``refine_delay`` seconds after a frame that is not full, the same settings
are rendered at the next level (``Engine.next_level``: draft -> preview -> full). A burst of
messages therefore costs one frame per render time, never a queue.

In a sequence, a frame change resets the settings the keyframes drive (``Engine.follows``: the
camera's orbit, the sun's angles) to the new frame's own, unless the same message sets them;
the frame messages carry their values and which of them follow the keyframes (``follows``).
"""
from __future__ import annotations

import asyncio
import base64
import ipaddress
import logging
import socket
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import PopvolError
from . import settings as S
from .engine import DRAFT, FULL, Engine

STATIC = Path(__file__).resolve().parent / "static"
REFINE_DELAY = 0.2          # seconds without input before a draft is refined
MAX_MESSAGE = 64 * 1024     # bytes: the page's messages are a few hundred
log = logging.getLogger("popvol.viewer")


@dataclass(frozen=True)
class Request:
    version: int
    settings: S.Settings
    level: str


class Session:
    """One open page: its settings, its pending-request slot and its render loop."""

    def __init__(self, ws, engine: Engine, worker: ThreadPoolExecutor, save_dir: Path,
                 refine_delay: float = REFINE_DELAY):
        self.ws, self.engine, self.worker = ws, engine, worker
        self.save_dir, self.refine_delay = save_dir, refine_delay
        self.settings = engine.initial
        self.version = 0
        self.slot: Request | None = Request(0, self.settings, FULL)   # the first frame
        self.save_wanted: S.Settings | None = None
        self.wake = asyncio.Event()

    async def run(self):
        """Receive messages until the page goes away; the render loop runs beside."""
        from starlette.websockets import WebSocketDisconnect
        await self.ws.send_json(init_message(self.engine))
        renderer = asyncio.create_task(self.render_loop())
        try:
            while True:
                msg = await self.ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                await self.handle(msg.get("text") if msg.get("text") is not None else msg.get("bytes"))
        except WebSocketDisconnect:
            pass
        finally:
            renderer.cancel()

    async def handle(self, text):
        """Check one message and update the slot (never waits for a render)."""
        try:
            m = S.parse_message(text, self.engine.distance_range, self.engine.has_sun, self.engine.has_key,
                                self.engine.frames)
        except PopvolError as e:
            await self.send_error(str(e))
            return
        except Exception as e:          # a bug: answer, log it, keep the websocket open
            log.exception("checking a message failed")
            await self.send_error(f"internal error while checking the message ({type(e).__name__}); please report it")
            return
        if m.kind == "save":
            self.save_wanted = self.settings
        else:
            changes = m.changes
            if "frame" in changes and changes["frame"] != self.settings.frame:
                # keyframes win on a frame change (as in Blender); a change in this message holds
                changes = {**{k: None for k in self.engine.follows}, **changes}
            self.settings = replace(self.settings, **changes)
            self.version += 1
            self.slot = Request(self.version, self.settings, DRAFT)    # overwrites any pending one
        self.wake.set()

    async def render_loop(self):
        """Take the latest request, render it on the worker, send it; refine after a pause."""
        loop = asyncio.get_running_loop()
        refine = None                       # the request to refine once input stops
        while True:
            if self.slot is None and self.save_wanted is None:
                self.wake.clear()
                if refine is None:
                    await self.wake.wait()
                else:
                    try:
                        await asyncio.wait_for(self.wake.wait(), self.refine_delay)
                    except TimeoutError:
                        if refine.version == self.version:
                            self.slot = Request(refine.version, refine.settings,
                                                self.engine.next_level(refine.level))
                        refine = None
                continue
            if self.save_wanted is not None:
                wanted, self.save_wanted = self.save_wanted, None
                try:
                    png, toml = await loop.run_in_executor(self.worker, self.engine.save, wanted, self.save_dir)
                    await self.ws.send_json({"type": "saved", "png": str(png), "toml": str(toml)})
                except PopvolError as e:
                    await self.send_error(f"save failed: {e}")
                continue
            req, self.slot = self.slot, None
            try:
                frame = await loop.run_in_executor(self.worker, self.engine.frame, req.settings, req.level)
            except PopvolError as e:
                await self.send_error(str(e))
                continue
            except Exception as e:          # a bug: say so on the page and in the log, keep serving
                log.exception("rendering failed")
                await self.send_error(f"internal error while rendering ({type(e).__name__}: {e}); please report it")
                continue
            follows = [k for k in self.engine.follows if getattr(req.settings, k) is None]
            await self.ws.send_json(frame_message(frame, req.version, self.engine, follows))
            refine = req if self.engine.next_level(req.level) else None

    async def send_error(self, message: str):
        from starlette.websockets import WebSocketDisconnect
        try:
            await self.ws.send_json({"type": "error", "message": message})
        except (WebSocketDisconnect, RuntimeError, OSError):    # the page has gone: nobody to tell
            log.debug("could not send an error to a closed page: %s", message)


def init_message(engine: Engine) -> dict:
    ranges = {k: [lo, hi] for k, (lo, hi, _) in S.RANGES.items()}
    ranges["camera_distance"] = list(engine.distance_range)
    return {"type": "init", "scene": engine.base.source, "settings": engine.initial.as_dict(),
            "ranges": ranges, "has_sun": engine.has_sun, "has_key": engine.has_key,
            "size": list(engine.size[FULL]), "draft_size": list(engine.size[DRAFT]),
            "resolution": engine.method.resolution, "draft_resolution": engine.draft_method.resolution,
            "camera_frame": S.orbit_frame(engine.base.camera.up).tolist(),
            "frames": engine.frames_info(), "follows": list(engine.follows)}


def frame_message(frame, version: int, engine: Engine, follows=()) -> dict:
    """A rendered frame for the page; ``follows``: the settings whose values in it are the
    keyframes' (the page adopts them unless it has changed them since)."""
    return {"type": "frame", "version": version, "level": frame.level, "frame": frame.settings.frame,
            "follows": list(follows),
            "width": frame.width, "height": frame.height, "resolution": frame.resolution,
            "propagated": frame.propagated, "seconds": frame.seconds,
            "solves": engine.solves, "renders": engine.renders,
            "settings": frame.settings.as_dict(), "png": base64.b64encode(frame.png).decode("ascii")}


class HostGuard:
    """ASGI middleware: refuses requests and websockets whose Host header names none of
    ``names`` (any port). A page elsewhere that reaches 127.0.0.1 through DNS rebinding sends
    its own name. (Starlette's TrustedHostMiddleware cannot parse "[::1]:port".)"""

    def __init__(self, app, names):
        self.app, self.names = app, set(names)

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            from starlette.datastructures import Headers
            from starlette.responses import PlainTextResponse
            from starlette.websockets import WebSocketClose
            host = Headers(scope=scope).get("host", "")
            name = host if host.endswith("]") else host.rsplit(":", 1)[0]
            if name not in self.names:
                refuse = (PlainTextResponse("Invalid host header", status_code=400) if scope["type"] == "http"
                          else WebSocketClose(code=1008))
                await refuse(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(engine: Engine, save_dir: Path, worker: ThreadPoolExecutor | None = None,
               allowed_hosts: list[str] | None = None, refine_delay: float = REFINE_DELAY):
    """The Starlette app: "/" the page, "/static/..." its files, "/ws" the websocket.

    allowed_hosts: host names accepted in the Host header, any port, IPv6 in brackets
        (DNS-rebinding guard); None accepts any.
    Websockets whose Origin is another site are refused (a web page elsewhere cannot drive
    the viewer).
    """
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.responses import FileResponse
    from starlette.routing import Mount, Route, WebSocketRoute
    from starlette.staticfiles import StaticFiles

    worker = worker or ThreadPoolExecutor(max_workers=1, thread_name_prefix="popvol-render")

    async def index(request):
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def websocket(ws):
        origin = ws.headers.get("origin")
        if origin is not None and origin.split("://", 1)[-1] != ws.headers.get("host"):
            await ws.close(code=1008)
            return
        await ws.accept()
        await Session(ws, engine, worker, Path(save_dir), refine_delay).run()

    middleware = [Middleware(HostGuard, names=allowed_hosts)] if allowed_hosts else []
    app = Starlette(routes=[Route("/", index), WebSocketRoute("/ws", websocket),
                            Mount("/static", StaticFiles(directory=STATIC, follow_symlink=False), name="static")],
                    middleware=middleware)
    app.state.engine = engine
    return app


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def listen(host: str, port: int) -> socket.socket:
    """A listening socket on host:port (port 0: any free port); one-line error if impossible."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise PopvolError(f"--port {port!r} must be an integer in [0, 65535]")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as e:
        raise PopvolError(f"--host {host}: cannot resolve ({e.strerror})") from None
    family, _, _, _, address = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as e:
        sock.close()
        raise PopvolError(f"cannot listen on {host}:{port} ({e.strerror})") from None
    sock.listen(64)
    return sock


def make_server(engine: Engine, sock: socket.socket, save_dir, refine_delay: float = REFINE_DELAY):
    """A uvicorn Server for the app on the listening ``sock`` (not started)."""
    import uvicorn
    hosts = None
    if is_loopback(sock.getsockname()[0]):
        hosts = ["127.0.0.1", "localhost", "[::1]"]
    app = create_app(engine, Path(save_dir), allowed_hosts=hosts, refine_delay=refine_delay)
    config = uvicorn.Config(app, log_level="warning", ws_max_size=MAX_MESSAGE, lifespan="off")
    return uvicorn.Server(config)


def url_of(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://{'[' + host + ']' if ':' in host else host}:{port}/"


def serve(engine: Engine, host: str = "127.0.0.1", port: int = 8765, open_browser: bool = True,
          save_dir=".", echo=print):
    """Warm the engine up, listen, print the address, open a browser; serve until Ctrl+C."""
    import webbrowser
    sock = listen(host, port)
    if not is_loopback(host):
        echo(f"popvol view: warning: listening on {host}, reachable from other machines; "
             "anyone who can reach it can drive the viewer and write views into the save folder")
    t0 = time.perf_counter()
    engine.frame(engine.initial, DRAFT)     # compiles or loads the kernels, first solution
    engine.frame(engine.initial, FULL)
    echo(f"popvol view: {engine.base.source}, ready in {time.perf_counter() - t0:.1f} s")
    url = url_of(sock)
    echo(f"popvol view: open {url}  (Ctrl+C to stop)")
    sys.stdout.flush()
    if open_browser:
        webbrowser.open(url)
    try:
        make_server(engine, sock, save_dir).run(sockets=[sock])
    except KeyboardInterrupt:              # uvicorn re-raises Ctrl+C after shutting down
        pass
    echo("popvol view: stopped")


@contextmanager
def running(engine: Engine, save_dir=".", host: str = "127.0.0.1", port: int = 0,
            refine_delay: float = REFINE_DELAY):
    """Serve in a background thread (for tests and benchmarks); yields the page's URL."""
    sock = listen(host, port)
    server = make_server(engine, sock, save_dir, refine_delay)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        t0 = time.monotonic()
        while not server.started:
            if not thread.is_alive() or time.monotonic() - t0 > 30:
                raise RuntimeError("the viewer's server did not start")
            time.sleep(0.01)
        yield url_of(sock)
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()
