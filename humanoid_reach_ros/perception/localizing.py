"""Localizing markers image by image (no ROS): the pipeline behind ``nodes/marker_localizer.py``.

Per image, in this order (the first failing check skips the image, counted, its reason kept):
valid intrinsics near the image stamp, a well-formed image of the calibrated size, the head
pose ``R_T_C`` by forward kinematics at the image stamp (from the joint-state buffer, fed
first with what arrived meanwhile), the still-camera skip (the camera where it was at the
last detection less than ``still_period_s`` ago: no new detection, eq. 1 would give the
same answer), then detection (:class:`~humanoid_reach_ros.perception.markers.MarkerDetector`)
and the pose chain of eq. 1, ``R_T_O = R_T_C C_T_M M_T_O``, for the target marker and,
when set, the [right, left] hand markers. It keeps the counts, rates and last values the
node's diagnostics report (:meth:`MarkerLocalizing.diagnostics`).

The node only converts messages and publishes: it hands over the image stamp, callables that
check the image and convert it to grey (called only when needed), and the joint states as
``(stamp, joints or None, reason)``; warnings go back through two callbacks (a skipped input,
a rejected marker).
"""
from __future__ import annotations

import math
import time

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.counters import Counters
from humanoid_reach_ros.geometry.camera import CameraCalibration
from humanoid_reach_ros.perception.markers import (JointStateBuffer, MarkerDetector, MarkerTable, camera_pose,
                                                   object_pose, same_camera_pose)

OK, WARN = 0, 1     # diagnostic_msgs/DiagnosticStatus levels

#: one joint state for the buffer: (stamp [s], model-ordered joint angles or None, why None)
JointSample = tuple[float, "np.ndarray | None", str]


def hand_target_poses(R_T_O: list[np.ndarray], workspace) -> list[pin.SE3]:
    """[right, left] hand targets from the two objects' 4x4 poses: their positions, and
    the workspace rule's orientations (``workspace`` given) or the objects' own."""
    out = []
    for side, T in zip(("right", "left"), R_T_O):
        p = np.asarray(T[:3, 3], float)
        R = T[:3, :3] if workspace is None else workspace.hand_rotation(side, p)
        out.append(pin.SE3(np.asarray(R, float), p))
    return out


@dataclass
class Localization:
    """What one image gave: every accepted marker's pose ``R_T_M``, the target object's
    ``R_T_O`` (one per detection of the target id) and the [right, left] hand targets
    (None unless both hand markers were accepted and had an orientation)."""
    markers: list[np.ndarray] = field(default_factory=list)
    targets: list[np.ndarray] = field(default_factory=list)
    hands: list[pin.SE3] | None = None


@dataclass
class LocalizerCounters(Counters):
    """What happened to the images (the localizer's ``/diagnostics``)."""

    images: int = 0
    localized: int = 0
    no_marker: int = 0
    rejected: int = 0
    skipped_still: int = 0
    hand_pairs: int = 0
    hand_pair_incomplete: int = 0
    skipped_image: int = 0
    skipped_camera_info: int = 0
    skipped_joint_states: int = 0
    skipped_hand_targets: int = 0


class MarkerLocalizing:
    """The per-image pipeline and its bookkeeping (counts, windows, last values)."""

    def __init__(self, model: Any, table: MarkerTable, detector: MarkerDetector, *, camera_frame_id: str,
                 target_marker_id: int, hand_ids: tuple[int, int] | None = None, workspace: Any = None,
                 joint_buffer_s: float = 2.0, max_stamp_gap_s: float = 0.05, camera_info_timeout_s: float = 2.0,
                 still_period_s: float = 0.5, on_skip: Callable[[str, int, str], None] | None = None,
                 on_rejection: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.model, self.table, self.detector = model, table, detector
        self.camera_frame_id = camera_frame_id
        self.target_marker_id = target_marker_id
        self.hand_ids, self.workspace = hand_ids, workspace
        self.max_stamp_gap_s = max_stamp_gap_s
        self.camera_info_timeout_s = camera_info_timeout_s
        self.still_period_s = still_period_s
        self.on_skip = on_skip or (lambda what, count, reason: None)
        self.on_rejection = on_rejection or (lambda text: None)
        self.clock = clock
        self.joints = JointStateBuffer(joint_buffer_s)
        self.intrinsics: CameraCalibration | None = None
        self._info_stamp_s = -math.inf
        self.counters = LocalizerCounters()
        self.last_skip_reason = ""
        self.last_rejection = ""
        self.last_error_px = math.nan
        self.last_target: np.ndarray | None = None
        self.last_hands: np.ndarray | None = None
        self._skipped_reported = 0
        self._window = self._new_window(clock())
        self._last_detection: tuple[np.ndarray, float] | None = None   # camera pose and time of the last detection
        self._js_gap_ms = self._js_gap_ms_total = 0.0
        self._js_newest = 0.0

    @staticmethod
    def _new_window(now: float) -> dict[str, float]:
        return {"start": now, "images": 0, "localized": 0, "max_process_s": 0.0}

    # ------------------------------------------------------------ inputs
    def skip(self, what: str, reason: str) -> None:
        """Count a skipped input (``image``, ``camera_info``, ``joint_states``, ``hand targets``)."""
        n = self.counters.count("skipped_" + what.replace(" ", "_"))
        self.last_skip_reason = f"{what}: {reason}"
        self.on_skip(what, n, reason)

    def add_joint_states(self, samples: Iterable[JointSample]) -> None:
        """Buffer joint states (a None sample is skipped with its reason), tracking the largest stamp gap."""
        for stamp, joints, reason in samples:
            if joints is None:
                self.skip("joint_states", reason)
                continue
            if self._js_newest > 0.0 and stamp > self._js_newest:
                gap = (stamp - self._js_newest) * 1e3
                self._js_gap_ms, self._js_gap_ms_total = max(self._js_gap_ms, gap), max(self._js_gap_ms_total, gap)
            self._js_newest = max(self._js_newest, stamp)
            self.joints.push(stamp, joints)

    def set_intrinsics(self, calibration: CameraCalibration, stamp_s: float) -> None:
        self.intrinsics = calibration
        self._info_stamp_s = stamp_s

    # ------------------------------------------------------------ images
    def localize(self, stamp_s: float, image_size: Callable[[], tuple[int, int]], gray: Callable[[], np.ndarray],
                 joint_states: Callable[[], Iterable[JointSample]] = lambda: ()) -> Localization | None:
        """One image: ``image_size()`` its ``(height, width)`` (``ValueError`` for a malformed one),
        ``gray()`` its grey pixels, ``joint_states()`` what arrived since the last call. None when
        the image was skipped or showed no accepted marker."""
        self.counters.count("images")
        self._window["images"] += 1
        cam = self.intrinsics
        if cam is None:
            self.skip("image", "no valid camera_info received yet")
            return None
        if abs(stamp_s - self._info_stamp_s) > self.camera_info_timeout_s:
            self.skip("image", f"the last valid camera_info is {abs(stamp_s - self._info_stamp_s):.1f} s away "
                               f"from the image stamp (> {self.camera_info_timeout_s:g} s)")
            return None
        try:
            height, width = image_size()
        except ValueError as exc:
            self.skip("image", str(exc))
            return None
        if (height, width) != (cam.height, cam.width):
            self.skip("image", f"image is {width} x {height} but camera_info says {cam.width} x {cam.height}")
            return None
        self.add_joint_states(joint_states())
        joints, reason = self.joints.at(stamp_s, self.max_stamp_gap_s)
        if joints is None:
            self.skip("image", f"no camera pose at the image stamp: {reason}")
            return None
        R_T_C = camera_pose(self.model, joints, self.camera_frame_id)
        if self._still(R_T_C):
            self.counters.count("skipped_still")
            return None
        result = self.detector.detect(gray(), cam.K, cam.D)
        for mid, why in result.rejected:
            self.counters.count("rejected")
            self.last_rejection = f"id {mid}: {why}"
            self.on_rejection(self.last_rejection)
        if not result.detections:
            self.counters.count("no_marker")
            return None
        out = Localization()
        hands: dict[int, np.ndarray] = {}
        for det in result.detections:
            out.markers.append(R_T_C @ det.C_T_M)
            self.last_error_px = det.reprojection_error_px
            if self.hand_ids is not None and det.marker_id in self.hand_ids:
                hands[det.marker_id] = object_pose(R_T_C, det.C_T_M, self.table.markers[det.marker_id].M_T_O)
            if det.marker_id == self.target_marker_id:
                R_T_O = object_pose(R_T_C, det.C_T_M, self.table.markers[det.marker_id].M_T_O)
                out.targets.append(R_T_O)
                self.last_target = R_T_O[:3, 3].copy()
                self.counters.count("localized")
                self._window["localized"] += 1
        if self.hand_ids is not None:
            out.hands = self._hands(hands)
        return out

    def processed(self, seconds: float) -> None:
        """An image took ``seconds`` from arrival to its last message (the window's longest)."""
        self._window["max_process_s"] = max(self._window["max_process_s"], seconds)

    def _still(self, R_T_C: np.ndarray) -> bool:
        """The camera is where it was at the last detection (1 mm, 1 mrad) and that was less than
        ``still_period_s`` ago: this image is skipped (else this pose becomes the last detection's)."""
        period, now, last = self.still_period_s, self.clock(), self._last_detection
        if period > 0 and self.hand_ids is None and last is not None and now - last[1] < period \
                and same_camera_pose(R_T_C, last[0]):
            return True
        self._last_detection = (R_T_C.copy(), now)
        return False

    def _hands(self, hands: dict[int, np.ndarray]) -> list[pin.SE3] | None:
        """[right, left] hand targets when both hand markers are in this image."""
        if not all(i in hands for i in self.hand_ids):
            self.counters.count("hand_pair_incomplete")
            return None
        try:
            out = hand_target_poses([hands[i] for i in self.hand_ids], self.workspace)
        except ValueError as exc:       # e.g. a marker at the shoulder: no orientation rule
            self.skip("hand targets", str(exc))
            return None
        self.counters.count("hand_pairs")
        self.last_hands = np.array([M.translation for M in out])
        return out

    # ------------------------------------------------------------ diagnostics
    def diagnostics(self) -> tuple[int, str, dict[str, Any]]:
        """``(level, message, values)`` of one diagnostics status; starts a new window."""
        now = self.clock()
        w, self._window = self._window, self._new_window(now)
        dt = max(now - w["start"], 1e-9)
        c = self.counters.snapshot()
        skipped = c.skipped_image + c.skipped_camera_info + c.skipped_joint_states
        values = {"images_total": c.images, "localized_total": c.localized, "no_marker_total": c.no_marker,
                  "rejected_total": c.rejected, "skipped_images_total": c.skipped_image,
                  "still_skipped_images_total": c.skipped_still,
                  "bad_camera_info_total": c.skipped_camera_info, "bad_joint_states_total": c.skipped_joint_states,
                  "image_rate_hz": w["images"] / dt, "localization_rate_hz": w["localized"] / dt,
                  "max_process_ms": 1e3 * w["max_process_s"], "last_reprojection_error_px": self.last_error_px,
                  "last_skip_reason": self.last_skip_reason, "last_rejection": self.last_rejection,
                  "joint_states_buffered": len(self.joints), "joint_states_max_gap_ms": self._js_gap_ms,
                  "joint_states_max_gap_ms_since_start": self._js_gap_ms_total}
        self._js_gap_ms = 0.0
        if self.hand_ids is not None:
            values.update({"hand_pairs_total": c.hand_pairs, "hand_pair_incomplete_total": c.hand_pair_incomplete,
                           "skipped_hand_targets_total": c.skipped_hand_targets})
        if self.last_target is not None:
            values.update({"target_x_m": self.last_target[0], "target_y_m": self.last_target[1],
                           "target_z_m": self.last_target[2]})
        level, message = OK, f"localizing at {w['localized'] / dt:.1f} Hz"
        new_skips, self._skipped_reported = skipped != self._skipped_reported, skipped
        if new_skips:
            level, message = WARN, f"skipping input: {self.last_skip_reason}"
        elif w["images"] == 0:
            level, message = WARN, "no images received"
        elif w["localized"] == 0:
            level, message = WARN, (f"target marker {self.target_marker_id} not seen"
                                    + (f" (last rejection: {self.last_rejection})" if self.last_rejection else ""))
        return level, message, values


__all__ = ["JointSample", "Localization", "MarkerLocalizing", "hand_target_poses"]
