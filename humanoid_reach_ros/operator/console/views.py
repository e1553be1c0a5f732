"""What the browser console shows, as compact frames: the voxel layers as changes, the robot's
capsules, the plan's ghost, the camera image with the marker outlined.

ROS-free: the node hands in numpy arrays and message stand-ins read by attribute. Every binary
frame is ``u32 header length | JSON header | payload`` (``pack``); the page (``static/console.js``)
reads the header, then the payload as the header's ``t`` says:

* ``voxels``: ``zlib(int16 keys (added + removed, 3 each))`` of one layer, ``full`` when the
  page must drop what it has first; a voxel of key ``k`` has its centre at ``(k + 0.5) h``;
* ``robot``: float32 capsule ends ``P0 | P1`` (S, 3) each, world frame; radii come once in the
  ``hello`` message (``RobotView.model``);
* ``ghost``: float32 frames x ``P0 | P1`` of the planned motion, with their times;
* ``image``: a JPEG, ``marker`` the outline's corners in image pixels (or null).
"""
from __future__ import annotations

import json
import math
import struct
import zlib
from typing import Any

import numpy as np

from humanoid_reach_ros.geometry.body_sweep import BodySweep
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel

KEY_LIMIT = 32000   # voxel keys are int16 on the wire: a layer's points beyond +-KEY_LIMIT voxels are dropped


def pack(header: dict[str, Any], payload: bytes = b"") -> bytes:
    """One binary WebSocket frame: ``u32 len(header) | header (JSON, UTF-8) | payload``."""
    head = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(head)) + head + payload


def unpack(frame: bytes) -> tuple[dict[str, Any], bytes]:
    """The inverse of :func:`pack` (tests and benches read the frames with it)."""
    (n,) = struct.unpack_from("<I", frame)
    return json.loads(frame[4:4 + n]), frame[4 + n:]


def voxel_keys(points: np.ndarray, resolution_m: float) -> np.ndarray:
    """Integer keys (N, 3) of voxel centres (N, 3) [m]: ``floor(p / h)``; non-finite points and
    keys beyond ``KEY_LIMIT`` are left out."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    k = np.floor(p / resolution_m).astype(np.int64)
    return np.unique(k[np.all(np.abs(k) <= KEY_LIMIT, axis=1)], axis=0)


def _codes(keys: np.ndarray) -> np.ndarray:
    """One int64 per key (sortable, for set differences)."""
    k = keys.astype(np.int64) + 32768
    return (k[:, 0] << 32) | (k[:, 1] << 16) | k[:, 2]


def _keys(codes: np.ndarray) -> np.ndarray:
    return np.stack([(codes >> 32) & 0xFFFF, (codes >> 16) & 0xFFFF, codes & 0xFFFF], axis=1) - 32768


class VoxelLayer:
    """One voxel layer (``/voxel_map``, ``/voxel_map/unobserved``) as the pages have it: each new
    cloud becomes the voxels added and removed since the last frame sent (a map at rest sends
    nothing); a page that joins gets the whole layer (``snapshot``)."""

    def __init__(self, name: str, resolution_m: float) -> None:
        if not (math.isfinite(resolution_m) and resolution_m > 0.0):
            raise ValueError(f"voxel resolution must be > 0, got {resolution_m}")
        self.name, self.resolution_m = name, float(resolution_m)
        self.sent = np.zeros(0, dtype=np.int64)      # codes the pages have (sorted)
        self.latest: np.ndarray | None = None        # codes of the last cloud, not yet sent

    def update(self, points: np.ndarray) -> None:
        """A new cloud of voxel centres (N, 3) [m] (kept until :meth:`delta`)."""
        self.latest = np.unique(_codes(voxel_keys(points, self.resolution_m)))

    def __len__(self) -> int:
        return int(self.sent.size if self.latest is None else self.latest.size)

    def delta(self) -> bytes | None:
        """The frame of what changed since the last one, or None when nothing did."""
        if self.latest is None:
            return None
        new, self.latest = self.latest, None
        added = np.setdiff1d(new, self.sent, assume_unique=True)
        removed = np.setdiff1d(self.sent, new, assume_unique=True)
        self.sent = new
        if not added.size and not removed.size:
            return None
        return self._frame(added, removed, full=False)

    def snapshot(self) -> bytes:
        """The whole layer as the pages have it (for a page that joins)."""
        return self._frame(self.sent, np.zeros(0, dtype=np.int64), full=True)

    def _frame(self, added: np.ndarray, removed: np.ndarray, full: bool) -> bytes:
        keys = np.concatenate([_keys(added), _keys(removed)]).astype("<i2")
        return pack({"t": "voxels", "layer": self.name, "full": full, "res": self.resolution_m,
                     "added": int(added.size), "removed": int(removed.size), "total": int(self.sent.size)},
                    zlib.compress(keys.tobytes(), 6))


class RobotView:
    """The robot drawn from its own collision model (``config/robots/<name>/collision.yaml``),
    standing on its feet as the planner assumes: capsule ends at a posture, the model once."""

    def __init__(self, model: RobotModel, collision_model: CollisionModel, move_threshold_m: float = 0.002) -> None:
        self.model, self.cm = model, collision_model
        self.sweep = BodySweep(model, collision_model, 0.0)
        self.move_threshold_m = float(move_threshold_m)
        self.sent: np.ndarray | None = None   # capsule ends (2 S, 3) of the last frame sent
        self._joints: np.ndarray | None = None  # the joints last looked at (unchanged: no forward kinematics)

    def model_info(self) -> dict[str, Any]:
        """The shapes' radii (as written, without padding) and names, and the robot's name."""
        return {"name": self.model.name, "radii": [round(float(r), 4) for r in self.cm.base_radii],
                "shapes": list(self.cm.names), "joints": list(self.model.joint_names)}

    def ends(self, joints: np.ndarray) -> np.ndarray:
        """Capsule ends ``P0 | P1`` (2 S, 3) at ``joints`` (model order)."""
        P0, P1, _ = self.sweep.capsules(joints, 0.0)
        return np.vstack([P0, P1])

    def frame(self, joints: np.ndarray, force: bool = False) -> bytes | None:
        """The robot frame at ``joints``; None when no capsule end moved ``move_threshold_m`` since
        the last frame (unless ``force``)."""
        j = np.asarray(joints, dtype=float)
        if not force and self._joints is not None and np.array_equal(j, self._joints):
            return None
        self._joints = j.copy()
        e = self.ends(j)
        if not force and self.sent is not None and float(np.max(np.abs(e - self.sent))) < self.move_threshold_m:
            return None
        self.sent = e
        return pack({"t": "robot", "shapes": self.cm.n_shapes}, e.astype("<f4").tobytes())

    def ghost(self, trajectory: Any, start: np.ndarray, max_frames: int) -> tuple[bytes, dict[str, Any]]:
        """The ghost frame of a ``trajectory_msgs/JointTrajectory`` (read by attribute): at most
        ``max_frames`` postures evenly in time (joints the trajectory does not name stay at
        ``start``), and a summary (duration, frames, the hand's path length is not known here)."""
        names = list(trajectory.joint_names)
        index = [self.model.joint_index.get(n) for n in names]
        unknown = [n for n, i in zip(names, index) if i is None]
        if unknown:
            raise ValueError(f"the plan names joints this robot does not have: {', '.join(unknown[:5])}")
        pts = list(trajectory.points)
        if not pts:
            raise ValueError("the plan has no points")
        t = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in pts])
        Q = np.array([list(p.positions) for p in pts], dtype=float)
        if Q.shape[1] != len(names):
            raise ValueError(f"the plan's points have {Q.shape[1]} positions for {len(names)} joints")
        times = np.linspace(t[0], t[-1], max(2, min(int(max_frames), len(pts) * 4)))
        frames = []
        for ti in times:
            j = np.array(start, dtype=float)
            j[index] = [np.interp(ti, t, Q[:, c]) for c in range(len(names))]
            frames.append(self.ends(j))
        data = np.stack(frames).astype("<f4")
        header = {"t": "ghost", "frames": len(frames), "shapes": self.cm.n_shapes,
                  "times": [round(float(x), 3) for x in times]}
        return pack(header, data.tobytes()), {"duration_s": float(t[-1]), "frames": len(frames)}


def image_frame(image: np.ndarray, detector: Any, quality: int, max_width: int) -> bytes:
    """A JPEG of a camera image ((H, W) grey or (H, W, 3) BGR) scaled down to ``max_width``, and
    the outlines of the markers ``detector`` finds in it (an OpenCV ArUco detector's
    ``detectMarkers``, on the scaled image: its corners (4, 2) px; None: no outlines)."""
    import cv2

    h, w = image.shape[:2]
    scale = min(1.0, max_width / float(w))
    if scale < 1.0:
        image = cv2.resize(image, (int(round(w * scale)), int(round(h * scale))), interpolation=cv2.INTER_AREA)
    outlines: list = []
    if detector is not None:
        corners, ids, _ = detector.detectMarkers(image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        if ids is not None:
            outlines = [np.round(np.asarray(c, dtype=float).reshape(4, 2), 1).tolist() for c in corners]
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return pack({"t": "image", "w": int(image.shape[1]), "h": int(image.shape[0]), "markers": outlines},
                jpeg.tobytes())
