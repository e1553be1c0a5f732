"""The robot's simulated head sensors, without ROS: one frame of the head camera's image, the
depth sensor's points and the optional stereo pair at a camera pose (``scene_sim`` publishes
them; ``sim/camera.py`` ray casts and shades).

A still head in an unchanged scene sees the same image: the ray cast and the images are
reused (:attr:`SensorFrame.reused`, so a publisher may reuse its messages too); the depth
noise is drawn anew for every frame, as a sensor's. :class:`RenderWindow` keeps the render
times and the frame count between two diagnostics reports.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from humanoid_reach_ros.counters import Counters
from humanoid_reach_ros.sim import camera as cam
from humanoid_reach_ros.sim.scene import Scene


@dataclasses.dataclass(frozen=True)
class SensorSettings:
    """What the sensors render: the image ``encoding`` (``cam.ENCODINGS``), the depth sensor's
    ``noise`` (None: no points), ``points_in_world`` (else the optical frame), the stereo
    ``baseline_m`` (None: no stereo pair), the styles and the ray cast's ``threads``."""

    encoding: str = "rgb8"
    noise: cam.DepthNoise | None = None
    points_in_world: bool = False
    baseline_m: float | None = None
    style: cam.RenderStyle = cam.RenderStyle()
    stereo_style: cam.RenderStyle = cam.RenderStyle(texture_amplitude=0.3)
    threads: int = 1


@dataclasses.dataclass
class SensorFrame:
    """One frame: ``image`` (H, W[, 3]) uint8, ``points`` (N, 3) or None, ``stereo`` (left,
    right) mono8 images or None; ``reused``: the same ray cast and images as the last frame."""

    image: np.ndarray
    points: np.ndarray | None
    stereo: tuple[np.ndarray, np.ndarray] | None
    reused: bool


class HeadSensors:
    """The head camera (and depth sensor, stereo pair) in ``scene`` (module doc)."""

    def __init__(self, scene: Scene, camera: cam.PinholeCamera, settings: SensorSettings, seed: int = 0) -> None:
        if settings.encoding not in cam.ENCODINGS:
            raise ValueError(f"image_encoding must be one of {cam.ENCODINGS}, got {settings.encoding!r}")
        self.scene_full, self.camera, self.settings = scene, camera, settings
        self.marker = cam.marker_print_from_scene(scene)
        self.rng = np.random.default_rng(seed)
        self.scene = scene
        self.disabled: list[str] = []
        self._cache: tuple | None = None       # (key, hits, image, stereo images)
        self.counters = SensorCounters()

    def without(self, names: list[str]) -> Scene:
        """The scene without the primitives ``names`` (empty strings ignored); KeyError naming
        the known ones for an unknown name."""
        return cam.without_primitives(self.scene_full, [n for n in names if n])

    def disable(self, names: list[str]) -> None:
        """Leave ``names`` out of the rendering from the next frame on (KeyError: unknown name)."""
        self.scene = self.without(names)
        self.disabled = [n for n in names if n]

    def frame(self, T_wc: np.ndarray) -> SensorFrame:
        """Render one frame at the camera pose ``T_wc`` (4x4, world)."""
        s, scene = self.settings, self.scene
        key = (np.round(T_wc, 9).tobytes(), id(scene))
        reused = self._cache is not None and self._cache[0] == key
        if reused:
            _, hits, image, stereo = self._cache
            self.counters.count("reused_frames")
        else:
            hits = cam.cast(scene, self.camera, T_wc, max_range_m=100.0, threads=s.threads)
            image = cam.render_image(scene, hits, self.marker, s.style, s.encoding)
            stereo = None
            if s.baseline_m is not None:
                stereo = tuple(cam.render_image(scene, cam.cast(scene, self.camera, T, max_range_m=100.0,
                                                                 threads=s.threads),
                                                self.marker, s.stereo_style, "mono8")
                               for T in cam.stereo_poses(T_wc, s.baseline_m))
            self._cache = (key, hits, image, stereo)
        points = None
        if s.noise is not None:
            points = cam.depth_points(hits, s.noise, self.rng)
            if s.points_in_world:
                points = points @ T_wc[:3, :3].T + T_wc[:3, 3]
        self.counters.count("frames")
        return SensorFrame(image, points, stereo, reused)


@dataclasses.dataclass
class SensorCounters(Counters):
    """What the head sensors did (``scene_sim``'s ``/diagnostics``)."""

    frames: int = 0
    reused_frames: int = 0
    bad_joint_states: int = 0
    last_bad_joint_states: str = ""


class RenderWindow:
    """Frames and render times since the last report."""

    def __init__(self) -> None:
        self.start, self.frames, self.max_s, self.sum_s = time.monotonic(), 0, 0.0, 0.0

    def add(self, seconds: float) -> None:
        self.frames += 1
        self.sum_s += seconds
        self.max_s = max(self.max_s, seconds)

    def report(self) -> dict:
        """``rate_hz``, ``mean_render_ms``, ``max_render_ms``, ``frames`` since the last call; restarts."""
        now = time.monotonic()
        out = {"frames": self.frames, "rate_hz": self.frames / max(now - self.start, 1e-9),
               "mean_render_ms": 1e3 * self.sum_s / self.frames if self.frames else 0.0,
               "max_render_ms": 1e3 * self.max_s}
        self.__init__()
        return out


__all__ = ["HeadSensors", "SensorSettings", "SensorFrame", "SensorCounters", "RenderWindow"]
