"""The operator console against a launched graph, in a real browser: for test_operator_console
and bench/console.py.

``start_graph`` starts the six nodes of ``reach.launch.py`` and ``operator_console`` (each with
its ``config/<name>.yaml``) in an isolated domain; ``Browser`` opens pages of the console in
Debian's ``chromium`` driven by Playwright (``executable_path``: Playwright's own browser
download does not work here), headless with software WebGL (``--enable-unsafe-swiftshader``);
``canvas_variance`` tells a drawn 3D view from a blank one.
"""
from __future__ import annotations

import shutil
import socket
from pathlib import Path
from typing import Any

import numpy as np

from humanoid_reach_ros.graph import GRAPH_NODES, Graph

CHROMIUM_CANDIDATES = ("chromium", "chromium-browser")
BROWSER_ARGS = ("--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--ignore-gpu-blocklist",
                "--no-sandbox")
SIM_JOINT_STATES_TIMEOUT_S = 2.0   # a shared 2-core machine can starve a node of /joint_states for a second
VALVE = (0.71, 0.03, 0.90)         # the plant's valve centre (config/scenes/plant.yaml, WGR eq. 3)


def chromium_path() -> str:
    """Debian's chromium (``make setup`` installs it); ``FileNotFoundError`` naming the remedy."""
    for name in CHROMIUM_CANDIDATES:
        if (path := shutil.which(name)) is not None:
            return path
    raise FileNotFoundError("chromium not found: make setup installs it (apt-get install chromium)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_graph(out: Path, env: dict[str, str], port: int | None, console_params: dict[str, Any] | None = None,
                nodes: tuple[str, ...] = GRAPH_NODES, node_params: dict[str, dict[str, Any]] | None = None) -> Graph:
    """The graph's nodes (``node_params``: parameters of some on top of their YAML files) and
    (``port`` not None) the console on ``port``; stop it with ``graph.stop()``."""
    graph = Graph(out, env)
    for name in nodes:
        params: dict[str, Any] = {}
        if name in ("reach_planner", "reach_executor"):
            params["joint_states_timeout_s"] = SIM_JOINT_STATES_TIMEOUT_S
        graph.start(name, {**params, **(node_params or {}).get(name, {})})
    if port is not None:
        start_console(graph, port, console_params)
    return graph


def start_console(graph: Graph, port: int, params: dict[str, Any] | None = None) -> Any:
    """``operator_console`` on ``port`` in ``graph`` (its NodeProcess)."""
    return graph.start("operator_console", {"port": port, **(params or {})})


class Browser:
    """Headless chromium through Playwright; ``page(url)`` opens one more page (1280 x 800)."""

    def __init__(self) -> None:
        from playwright.sync_api import sync_playwright
        self._pw = sync_playwright().start()
        try:
            self.browser = self._pw.chromium.launch(executable_path=chromium_path(), headless=True,
                                                    args=list(BROWSER_ARGS))
        except Exception:
            self._pw.stop()
            raise
        self.console: list[str] = []

    def page(self, url: str, width: int = 1280, height: int = 800) -> Any:
        page = self.browser.new_page(viewport={"width": width, "height": height})
        page.on("console", lambda m: self.console.append(f"{m.type}: {m.text}"))
        page.on("pageerror", lambda e: self.console.append(f"pageerror: {e}"))
        page.goto(url)
        return page

    def close(self) -> None:
        try:
            self.browser.close()
        finally:
            self._pw.stop()


def canvas_variance(page: Any, selector: str = "#scene") -> float:
    """Variance of the grey levels of a screenshot of the canvas (a blank canvas: 0)."""
    import cv2
    png = page.locator(selector).screenshot()
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    return float(np.var(img.astype(float)))


class ConsolePage:
    """One page of the console, driven as an operator does: buttons and clicks, each action
    awaited until its result (``window.hr``: what the page shows, static/console.js)."""

    def __init__(self, page: Any) -> None:
        self.page = page

    def hr(self, expr: str) -> Any:
        return self.page.evaluate(f"window.hr.{expr}")

    def wait(self, condition: Any, timeout_s: float, what: str) -> Any:
        from humanoid_reach_ros.graph import wait_for
        return wait_for(condition, timeout_s, what, on_timeout=lambda: self.page.inner_text("#log"),
                        step=lambda: self.page.wait_for_timeout(100))

    def take(self) -> None:
        self.page.click("#take")
        self.wait(lambda: self.hr("holder === window.hr.page"), 30.0, "the controls taken")

    def act(self, button: str, timeout_s: float) -> tuple[dict, float]:
        """Click ``button`` (once it is enabled) and await its result: (result, seconds)."""
        import time
        self.wait(lambda: not self.page.is_disabled(f"#{button}"), 30.0, f"{button} enabled")
        n = len(self.hr("results"))
        t0 = time.monotonic()
        self.page.click(f"#{button}")
        self.wait(lambda: len(self.hr("results")) > n, timeout_s, f"the result of {button}")
        return self.hr("results")[n], time.monotonic() - t0

    def click_at(self, point: tuple[float, float, float]) -> list[float] | None:
        """Click the 3D view where ``point`` [m, world] is drawn; the target picked (or None)."""
        at = self.hr(f"project({point[0]}, {point[1]}, {point[2]})")
        self.page.mouse.click(at["x"], at["y"])
        return self.hr("picked")
