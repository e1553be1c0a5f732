"""The console's web server (aiohttp): the page, three.js, and one WebSocket per page.

:class:`ConsoleFeed` reads the robot's latest inputs when a frame is due (``/joint_states`` at
200 Hz and the images at 10 Hz are taken on demand, never delivered one by one).
:class:`ConsoleServer` runs the event loop in a thread of its own; every ``update_period_s`` it
sends each page what changed, throttled: the robot when a capsule moved (``RobotView``), the
voxel layers as changes at most every ``map_period_s``, the camera image at most every
``image_period_s`` and only a new one, the status when it changed (and every ``STATUS_EVERY_S``).
Each page has one queue, sent in order; a page that lags gets no images until it caught up. A
page's requests go to ``control.ConsoleControl``.

ROS-free; ``nodes/operator_console.py`` is the adapter.
"""
from __future__ import annotations

import asyncio
import hashlib
import itertools
import json
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from humanoid_reach_ros.operator.console.control import ConsoleControl
from humanoid_reach_ros.operator.console.views import RobotView, VoxelLayer, image_frame, pack

STATIC_DIR = Path(__file__).resolve().parent / "static"
PACKAGE_ROOT = Path(__file__).resolve().parents[3]          # the checkout (node_modules/ beside package.json)
STATUS_EVERY_S = 5.0           # the status goes out at least this often (a page sees the console is alive)
MAX_REQUEST_BYTES = 4096       # a page's request larger than this is refused unread
SLOW_PAGE_QUEUE = 20           # a page with more messages than this waiting gets no image until it took them


@dataclass(frozen=True)
class ConsoleConfig:
    host: str = "127.0.0.1"
    port: int = 8765
    update_period_s: float = 0.1
    map_period_s: float = 1.0
    image_period_s: float = 0.5
    image_quality: int = 60
    image_max_width: int = 480
    three_js_dir: str = ""     # "": node_modules/three of the checkout


def three_js_dir(configured: str) -> Path:
    """Where three.js is (``make setup``'s ``npm ci``): the parameter, else the checkout's
    ``node_modules/three``; ``FileNotFoundError`` naming the remedy."""
    d = Path(configured) if configured else PACKAGE_ROOT / "node_modules" / "three"
    if not (d / "build" / "three.module.js").is_file():
        raise FileNotFoundError(f"three.js not found in {d} (build/three.module.js): run `make setup` (npm ci) or "
                                f"set three_js_dir")
    return d


class ConsoleFeed:
    """The robot's inputs as the console reads them: ``joints()`` the latest joints (or None) and
    ``image()`` the latest camera image (grey (H, W)) when a new one came since the last call (else
    None), both taken on demand when a frame is due (the node's ``LatestOnDemand``: no wake-up per
    message); the voxel layers and the status handed in by the node's callbacks."""

    def __init__(self, occupied: VoxelLayer, unobserved: VoxelLayer) -> None:
        self.lock = threading.Lock()
        self.joints: Callable[[], np.ndarray | None] = lambda: None
        self.image: Callable[[], np.ndarray | None] = lambda: None
        self.layers = {"occupied": occupied, "unobserved": unobserved}
        self.pending: dict[str, np.ndarray] = {}
        self.occupied_points = np.zeros((0, 3))
        self.status: dict[str, Any] = {}

    def set_layer(self, name: str, points: np.ndarray) -> None:
        with self.lock:
            self.pending[name] = points
            if name == "occupied":
                self.occupied_points = np.asarray(points, dtype=float).reshape(-1, 3)

    def set_status(self, **values: Any) -> None:
        with self.lock:
            self.status.update(values)

    def current_joints(self) -> np.ndarray | None:
        return self.joints()

    def map_distance(self, point: list[float]) -> float:
        """Distance [m] of ``point`` to the nearest occupied voxel centre (inf: no map)."""
        with self.lock:
            pts = self.occupied_points
        if not len(pts):
            return math.inf
        return float(np.sqrt(np.min(np.sum((pts - np.asarray(point, float)) ** 2, axis=1))))


class ConsoleServer:
    """The page, three.js and the WebSocket, in an event loop on a thread of its own."""

    def __init__(self, config: ConsoleConfig, feed: ConsoleFeed, robot: RobotView, control: ConsoleControl,
                 log: Callable[[str], None] = print, three_dir: Path | None = None, detector: Any = None) -> None:
        self.config, self.feed, self.robot, self.control, self.log = config, feed, robot, control, log
        self.detector = detector     # an OpenCV ArUco detector (marker_detector) or None: no outlines
        self.three_dir = three_dir or three_js_dir(config.three_js_dir)
        self.pages: dict[int, Any] = {}
        self.queues: dict[int, asyncio.Queue] = {}   # per page, in order: one sender task each
        self.ids = itertools.count(1)
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread: threading.Thread | None = None
        self.ready = threading.Event()
        self.error: BaseException | None = None
        self.sent_bytes = 0          # to all pages since start (the bench reads it through /stats)
        self._last_status: str = ""
        self._status_t = 0.0
        self._map_t = -math.inf
        self._image_t = -math.inf
        self._image_hash = b""
        self._stop: asyncio.Event | None = None
        self._last_failure = ""
        self.url = ""

    # ------------------------------------------------------------ thread-safe entry points
    def emit(self, message: dict[str, Any], to: Any = None) -> None:
        """A JSON message to every page (``to`` None) or to page ``to``, from any thread."""
        self._call(self._send_text, json.dumps(message, separators=(",", ":"), allow_nan=False), to)

    def emit_frame(self, frame: bytes) -> None:
        self._call(self._send_bytes, frame, None)

    def _call(self, fn: Callable, *args: Any) -> None:
        loop = self.loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(fn, *args)

    def start(self, timeout_s: float = 60.0) -> str:
        """Start serving; the page's URL. ``OSError`` when the port cannot be had."""
        self.thread = threading.Thread(target=self._serve, name="console-server", daemon=True)
        self.thread.start()
        if not self.ready.wait(timeout_s):
            raise OSError(f"the console's server did not start within {timeout_s:g} s")
        if self.error is not None:
            raise OSError(f"cannot serve on {self.config.host}:{self.config.port}: {self.error}") from self.error
        return self.url

    def stop(self) -> None:
        if self.loop is not None and self._stop is not None:
            self.loop.call_soon_threadsafe(self._stop.set)
        if self.thread is not None:
            self.thread.join(5.0)

    # ------------------------------------------------------------ the loop
    def _serve(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:   # noqa: BLE001 - reported to start() / the log
            self.error = exc
            self.ready.set()

    async def _main(self) -> None:
        from aiohttp import web

        self.loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/stats", self._stats)
        app.router.add_static("/static/", STATIC_DIR)
        app.router.add_static("/three/build/", self.three_dir / "build")
        app.router.add_static("/three/examples/jsm/", self.three_dir / "examples" / "jsm")
        runner = web.AppRunner(app, access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, self.config.host, self.config.port)
        try:
            await site.start()
        except OSError as exc:
            self.error = exc
            self.ready.set()
            await runner.cleanup()
            return
        self.url = f"http://{self.config.host}:{self.config.port}/"
        self.ready.set()
        ticker = asyncio.ensure_future(self._ticks())
        await self._stop.wait()
        ticker.cancel()
        for ws in list(self.pages.values()):
            await ws.close()
        await runner.cleanup()

    async def _index(self, request: Any) -> Any:
        from aiohttp import web
        return web.FileResponse(STATIC_DIR / "index.html")

    async def _stats(self, request: Any) -> Any:
        from aiohttp import web
        return web.json_response({"pages": len(self.pages), "sent_bytes": self.sent_bytes,
                                  "voxels": {k: len(v) for k, v in self.feed.layers.items()}})

    async def _ws(self, request: Any) -> Any:
        from aiohttp import WSMsgType, web

        ws = web.WebSocketResponse(max_msg_size=MAX_REQUEST_BYTES, heartbeat=20.0)
        await ws.prepare(request)
        page = next(self.ids)
        queue: asyncio.Queue = asyncio.Queue()
        self.pages[page], self.queues[page] = ws, queue
        sender = asyncio.ensure_future(self._sender(ws, queue))
        self.log(f"page {page} connected from {request.remote} ({len(self.pages)} open)")
        try:
            self._welcome(page)
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    try:
                        req = json.loads(msg.data)
                    except ValueError as exc:
                        self._send_text(json.dumps({"t": "error", "op": None, "text": f"not JSON: {exc}"}), page)
                        continue
                    await asyncio.get_running_loop().run_in_executor(None, self.control.handle, page, req)
                    self._last_status = ""   # the controls may have changed: status at the next tick
                elif msg.type == WSMsgType.BINARY:
                    self._send_text(json.dumps({"t": "error", "op": None, "text": "requests are JSON text"}), page)
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.pages.pop(page, None)
            self.queues.pop(page, None)
            sender.cancel()
            self.control.left(page)
            self._last_status = ""
            self.log(f"page {page} closed ({len(self.pages)} open)")
        return ws

    async def _sender(self, ws: Any, queue: asyncio.Queue) -> None:
        """A page's messages in the order they were made."""
        while True:
            item = await queue.get()
            if ws.closed:
                continue
            try:
                await (ws.send_str(item) if isinstance(item, str) else ws.send_bytes(item))
            except (ConnectionError, RuntimeError):   # the page went away meanwhile
                pass

    def _welcome(self, page: int) -> None:
        self._send_text(json.dumps({"t": "hello", "page": page, "robot": self.robot.model_info()}), page)
        for layer in self.feed.layers.values():
            self._send_bytes(layer.snapshot(), page)
        joints = self.feed.current_joints()
        if joints is not None:
            self._send_bytes(self.robot.frame(joints, force=True), page)
        self._image_hash = b""    # the next image goes out even if unchanged
        self._last_status = ""

    def _send_text(self, text: str, to: Any) -> None:
        for page, queue in list(self.queues.items()):
            if to is None or page == to:
                self.sent_bytes += len(text)
                queue.put_nowait(text)

    def _send_bytes(self, frame: bytes, to: Any = None, skip_slow: bool = False) -> None:
        for page, queue in list(self.queues.items()):
            if to is None or page == to:
                if skip_slow and queue.qsize() > SLOW_PAGE_QUEUE:   # a page that lags gets no more images
                    continue
                self.sent_bytes += len(frame)
                queue.put_nowait(frame)

    async def _ticks(self) -> None:
        period = self.config.update_period_s
        while True:
            await asyncio.sleep(period)
            if not self.pages:
                continue
            try:
                self._tick()
            except Exception as exc:   # a frame that cannot be made is logged (once per kind); the console goes on
                text = f"update failed: {type(exc).__name__}: {exc}"
                if text != self._last_failure:
                    self._last_failure = text
                    self.log(text)

    def _tick(self) -> None:
        now = time.monotonic()
        joints = self.feed.current_joints()
        if joints is not None and (frame := self.robot.frame(joints)) is not None:
            self._send_bytes(frame)
        if now - self._map_t >= self.config.map_period_s:
            with self.feed.lock:
                pending, self.feed.pending = self.feed.pending, {}
            for name, points in pending.items():
                layer = self.feed.layers[name]
                layer.update(points)
                if (frame := layer.delta()) is not None:
                    self._send_bytes(frame)
                    self._map_t = now
        if now - self._image_t >= self.config.image_period_s:
            self._image_t = now
            gray = self.feed.image()
            if gray is not None:
                digest = hashlib.blake2b(gray.tobytes(), digest_size=16).digest()
                if digest != self._image_hash:    # a still robot in a still scene: the same image, not sent again
                    self._image_hash = digest
                    self._send_bytes(image_frame(gray, self.detector, self.config.image_quality,
                                                 self.config.image_max_width), skip_slow=True)
        status = {**self.feed.status, **self.control.state(),
                  "voxels": {k: len(v) for k, v in self.feed.layers.items()}}
        text = json.dumps({"t": "status", **status}, separators=(",", ":"), default=float)
        if text != self._last_status or now - self._status_t >= STATUS_EVERY_S:
            self._last_status, self._status_t = text, now
            self._send_text(text, None)


def marker_detector(dictionary: str) -> Any:
    """An OpenCV ArUco detector of ``dictionary`` (``ValueError`` for an unknown one)."""
    import cv2
    if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
        raise ValueError(f"marker_dictionary: unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50)")
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)),
                                   cv2.aruco.DetectorParameters())


__all__ = ["ConsoleConfig", "ConsoleFeed", "ConsoleServer", "marker_detector", "pack",
           "three_js_dir"]
