"""AR-marker localization of the target object (dissertation 004, Sec. 3.2 / 4.5.4, eq. 1).

The object's pose in the robot (world) frame is the chain

    R_T_O = R_T_C  C_T_M  M_T_O                                                (eq. 1)

* ``C_T_M``: the marker's pose in the camera (optical) frame, from the image: ArUco
  detection (OpenCV ``cv2.aruco.ArucoDetector``, sub-pixel corner refinement), corners
  re-estimated as intersections of lines fitted to the four outer edges
  (:func:`refine_corners_by_edges`: ``cornerSubPix`` corners are biased inwards by
  ~0.15 px, which is 5 mm in depth at 1 m for a 10 cm marker; used when the camera has no
  distortion coefficients and the fit is at least as consistent), and the
  planar-square PnP of Collins & Bartoli (``cv2.SOLVEPNP_IPPE_SQUARE``, both solutions
  scored, the lower reprojection error kept); detections whose RMS reprojection error
  exceeds a threshold are rejected;
* ``R_T_C``: the camera's pose from forward kinematics at the image time stamp
  (:class:`JointStateBuffer` interpolates the joint angles between the two joint states
  that bracket the stamp, and refuses a look-up whose error bound exceeds a joint-angle
  tolerance: lost ``/joint_states`` while the head moves);
* ``M_T_O``: where the marker is on the object, configuration per marker id
  (:class:`MarkerTable`, from ``config/marker_localizer.yaml``).

The dissertation used ARToolKit; ArUco with IPPE is the OpenCV equivalent (named
substitution). No lens distortion is modelled unless the camera_info gives it.

This module never imports rclpy.
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.yaml_checks import number, positive, top_level

#: the parameters of config/marker_localizer.yaml that describe the markers
MARKER_KEYS = ("dictionary", "marker_ids", "marker_sizes_m", "marker_object_poses")


# ----------------------------------------------------------------- transforms
def transform(position: Sequence[float], quat_xyzw: Sequence[float]) -> np.ndarray:
    """4x4 homogeneous transform from a position and a unit quaternion (x, y, z, w)."""
    x, y, z, w = (float(v) for v in quat_xyzw)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or abs(n - 1.0) > 1e-3:
        raise ValueError(f"quaternion {list(quat_xyzw)} is not unit length (norm {n:.6f})")
    x, y, z, w = x / n, y / n, z / n, w / n
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = position
    return T


def object_pose(R_T_C: np.ndarray, C_T_M: np.ndarray, M_T_O: np.ndarray) -> np.ndarray:
    """Eq. 1: ``R_T_O = R_T_C C_T_M M_T_O`` (4x4 each)."""
    return np.asarray(R_T_C) @ np.asarray(C_T_M) @ np.asarray(M_T_O)


def marker_corners(size_m: float) -> np.ndarray:
    """Corners (4, 3) of a square marker in its own frame (z out of the face, x right, y up),
    in ArUco / IPPE_SQUARE order: top-left, top-right, bottom-right, bottom-left."""
    h = 0.5 * size_m
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


# ----------------------------------------------------------------- marker table
@dataclass(frozen=True)
class MarkerSpec:
    """One known marker: id, printed black-square edge ``size_m`` and ``M_T_O`` (4x4), the
    object's pose in the marker frame."""

    marker_id: int
    size_m: float
    M_T_O: np.ndarray


@dataclass(frozen=True)
class MarkerTable:
    """The ArUco dictionary and the known markers by id."""

    dictionary: str
    markers: Mapping[int, MarkerSpec]


def marker_table(dictionary: Any, ids: Any, sizes_m: Any, object_poses: Any, where: str = "markers") -> MarkerTable:
    """Validated :class:`MarkerTable` from parallel lists: ``ids`` (K,), ``sizes_m`` (K,) and
    ``object_poses`` (7 K: x, y, z, qx, qy, qz, qw of M_T_O per id). ``ValueError`` naming
    the bad entry: unknown dictionary, lengths that disagree, duplicate or out-of-dictionary
    ids, non-positive sizes, non-finite numbers, non-unit quaternions."""
    if not isinstance(dictionary, str) or not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
        raise ValueError(f"{where}: dictionary: unknown ArUco dictionary {dictionary!r} (e.g. DICT_4X4_50)")
    n_ids = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)).bytesList.shape[0]
    ids, sizes, poses = list(ids or []), list(sizes_m or []), list(object_poses or [])
    if not ids:
        raise ValueError(f"{where}: marker_ids must list at least one marker")
    if len(sizes) != len(ids) or len(poses) != 7 * len(ids):
        raise ValueError(f"{where}: {len(ids)} marker_ids need {len(ids)} marker_sizes_m (got {len(sizes)}) and "
                         f"{7 * len(ids)} marker_object_poses numbers (x y z qx qy qz qw per id; got {len(poses)})")
    out: dict[int, MarkerSpec] = {}
    for k, mid in enumerate(ids):
        w = f"{where}: marker #{k}"
        if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid < n_ids:
            raise ValueError(f"{w}: id must be an integer in 0..{n_ids - 1} for {dictionary}, got {mid!r}")
        if mid in out:
            raise ValueError(f"{w}: duplicate id {mid}")
        size = positive(sizes[k], f"{w} (id {mid}) size_m")
        vals = [number(v, f"{w} (id {mid}) object pose") for v in poses[7 * k:7 * k + 7]]
        try:
            T = transform(vals[:3], vals[3:])
        except ValueError as exc:
            raise ValueError(f"{w} (id {mid}) object pose: {exc}") from None
        out[mid] = MarkerSpec(mid, size, T)
    return MarkerTable(dictionary, out)


def load_marker_config(path: str | Path = "marker_localizer.yaml") -> MarkerTable:
    """The :class:`MarkerTable` of a marker_localizer parameter file (``/**: ros__parameters``
    or ``marker_localizer: ros__parameters``); relative paths resolve under ``config/``."""
    p = config_path(str(path))
    where = f"marker config {p}"
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{where}: not valid YAML: {exc}") from None
    top_level(doc, ("/**", "marker_localizer", "/marker_localizer"), where)
    section = next(iter(doc.values()))
    if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
        raise ValueError(f"{where}: expected '<node>: ros__parameters: {{...}}'")
    params = section["ros__parameters"]
    missing = [k for k in MARKER_KEYS if k not in params]
    if missing:
        raise ValueError(f"{where}: missing parameter(s) {missing}")
    return marker_table(params["dictionary"], params["marker_ids"], params["marker_sizes_m"],
                        params["marker_object_poses"], where)


# ----------------------------------------------------------------- detection + PnP
@dataclass(frozen=True)
class MarkerDetection:
    """A marker seen in one image: ``C_T_M`` (4x4, marker in the optical frame), RMS
    reprojection error [px] of the chosen IPPE solution, image corners (4, 2), and whether
    the corners come from the edge-line fit (:func:`refine_corners_by_edges`)."""

    marker_id: int
    C_T_M: np.ndarray
    reprojection_error_px: float
    corners: np.ndarray
    edge_refined: bool = False


@dataclass(frozen=True)
class DetectionResult:
    """Accepted detections, and the rejected ones as (id, reason)."""

    detections: tuple[MarkerDetection, ...]
    rejected: tuple[tuple[int, str], ...]


class MarkerDetector:
    """ArUco detection (sub-pixel corners), edge-line corner refinement and IPPE-square PnP
    for the markers of a table."""

    def __init__(self, table: MarkerTable, max_reprojection_error_px: float = 1.0,
                 corner_refine_window_px: int = 5, edge_refinement: bool = True) -> None:
        if not max_reprojection_error_px > 0.0:
            raise ValueError(f"max_reprojection_error_px must be > 0, got {max_reprojection_error_px}")
        self.table = table
        self.max_reprojection_error_px = float(max_reprojection_error_px)
        self.edge_refinement = bool(edge_refinement)
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, table.dictionary))
        self.cells = int(dictionary.markerSize) + 2
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        params.cornerRefinementWinSize = int(corner_refine_window_px)
        params.cornerRefinementMinAccuracy = 0.01
        params.cornerRefinementMaxIterations = 50
        self.detector = cv2.aruco.ArucoDetector(dictionary, params)

    def detect(self, gray: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None) -> DetectionResult:
        """Markers of the table in a mono8 image (H, W) with intrinsics ``K`` (3x3) and
        distortion coefficients ``dist`` (None: none)."""
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"expected a mono8 image (H, W) uint8, got {gray.shape} {gray.dtype}")
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        D = np.zeros(5) if dist is None or len(dist) == 0 else np.asarray(dist, dtype=np.float64)
        corners, ids, _ = self.detector.detectMarkers(gray)
        found, rejected = [], []
        if ids is None:
            return DetectionResult((), ())
        for c, mid in zip(corners, ids.ravel()):
            mid = int(mid)
            spec = self.table.markers.get(mid)
            if spec is None:
                rejected.append((mid, "id not in the marker table"))
                continue
            img = np.asarray(c, dtype=np.float64).reshape(4, 2)
            C_T_M, err = solve_marker_pose(img, spec.size_m, K, D)
            # edges are straight lines only in an undistorted image
            use_edges = self.edge_refinement and not np.any(D)
            refined = refine_corners_by_edges(gray, img, self.cells) if use_edges else None
            if refined is not None:
                T_ref, err_ref = solve_marker_pose(refined, spec.size_m, K, D)
                if err_ref <= max(err, 0.5 * self.max_reprojection_error_px):
                    img, C_T_M, err = refined, T_ref, err_ref
                else:
                    refined = None   # the edge fit is less consistent than the detector's corners
            if not err <= self.max_reprojection_error_px:
                rejected.append((mid, f"reprojection error {err:.2f} px > {self.max_reprojection_error_px:g} px"))
                continue
            found.append(MarkerDetection(mid, C_T_M, err, img, refined is not None))
        return DetectionResult(tuple(found), tuple(rejected))


def refine_corners_by_edges(gray: np.ndarray, corners: np.ndarray, cells: int, samples: int = 12,
                            max_shift_cells: float = 0.75) -> np.ndarray | None:
    """Corners (4, 2) as intersections of lines fitted to the marker's four outer edges.

    Sub-pixel corner detectors (``cornerSubPix``) are biased towards the inside of an
    L-shaped corner once the image is blurred by pixel integration; edges are not. Along
    each side, ``samples`` intensity profiles across the edge (bilinear, quarter-pixel steps,
    at most 0.8 of a cell deep so they stay on the black border and its white margin) give
    the edge's position by the area rule (the profile normalised between its darkest and
    brightest sample integrates to the length of its bright part, whatever the blur); a line
    is fitted through them (total least squares) and adjacent lines are intersected -- the
    quad line fit of AprilTag, simplified (one pass, no gradient weighting). Returns None
    (keep the detector's corners) when a side has fewer than 4 usable profiles or a corner
    would move by more than ``max_shift_cells`` cells (``cells`` across the marker, border
    included)."""
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    centre = c.mean(axis=0)
    side_px = np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)
    cell_px = side_px.min() / cells
    depth = min(0.8 * cell_px, 6.0)
    if depth < 1.0:
        return None
    step = 0.25
    offsets = np.arange(-depth, depth + 1e-9, step)
    ts = np.linspace(0.2, 0.8, samples)
    lines = []
    for i in range(4):
        a, b = c[i], c[(i + 1) % 4]
        e = (b - a) / np.linalg.norm(b - a)
        nrm = np.array([-e[1], e[0]])
        if np.dot(0.5 * (a + b) - centre, nrm) < 0.0:
            nrm = -nrm                                   # outward: black inside, white outside
        base = a + ts[:, None] * (b - a)
        pts = base[:, None, :] + offsets[None, :, None] * nrm
        prof = cv2.remap(gray.astype(np.float32), pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        edge = []
        for k in range(len(ts)):
            p = prof[k]
            lo, hi = float(p.min()), float(p.max())
            if hi - lo < 20.0:
                continue
            above = p >= 0.5 * (lo + hi)
            j = np.flatnonzero(~above[:-1] & above[1:])      # exactly one dark -> bright step outward
            if len(j) != 1:
                continue
            # area rule: the bright part of the normalised profile spans (s_end - edge)
            w = (p - lo) / (hi - lo)
            bright = float(np.sum(0.5 * (w[1:] + w[:-1])) * step)
            edge.append(base[k] + (offsets[-1] - bright) * nrm)
        if len(edge) < 4:
            return None
        line = _fit_line(np.asarray(edge))
        if line is None:
            return None
        lines.append(line)
    out = np.empty((4, 2))
    for i in range(4):
        (m0, d0), (m1, d1) = lines[i - 1], lines[i]          # sides ending and starting at corner i
        A = np.column_stack([d0, -d1])
        if abs(np.linalg.det(A)) < 1e-9:
            return None
        s = np.linalg.solve(A, m1 - m0)
        out[i] = m0 + s[0] * d0
    if np.max(np.linalg.norm(out - c, axis=1)) > max(1.5, max_shift_cells * cell_px):
        return None
    return out


def _fit_line(q: np.ndarray, inlier_px: float = 0.3) -> tuple[np.ndarray, np.ndarray] | None:
    """Total-least-squares line (point, unit direction) through edge points (K, 2), refitted
    once on the points within ``inlier_px`` of the first fit (an occluding spoke or rim
    crossing the edge makes outliers); None with fewer than 4 inliers."""
    for _ in range(2):
        if len(q) < 4:
            return None
        m = q.mean(axis=0)
        d = np.linalg.svd(q - m)[2][0]
        resid = np.abs((q - m) @ np.array([-d[1], d[0]]))
        keep = resid <= inlier_px
        if keep.all():
            break
        q = q[keep]
    return (m, d) if len(q) >= 4 else None


def solve_marker_pose(image_corners: np.ndarray, size_m: float, K: np.ndarray,
                      dist: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """``C_T_M`` (4x4) and RMS reprojection error [px] of a square marker from its four
    image corners (ArUco order) by IPPE_SQUARE; of the two IPPE solutions the one with the
    lower reprojection error (inf when PnP fails)."""
    obj = marker_corners(size_m)
    D = np.zeros(5) if dist is None else np.asarray(dist, dtype=np.float64)
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, np.asarray(image_corners, np.float64).reshape(4, 1, 2),
                                                np.asarray(K, np.float64), D, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not n:
        return np.eye(4), math.inf
    errs = np.asarray(errs, dtype=float).ravel()
    best = int(np.argmin(errs))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvecs[best])[0]
    T[:3, 3] = np.asarray(tvecs[best]).ravel()
    return T, float(errs[best])


# ----------------------------------------------------------------- joint states by stamp
class JointStateBuffer:
    """Joint-angle vectors by stamp over the last ``window_s`` seconds (at most
    ``max_items``), for ``R_T_C`` at an image stamp.

    A stamp between buffered states is linearly interpolated, one outside the buffered
    range by at most ``max_gap_s`` takes the nearest state -- but only when the joint-angle
    error this may hide is at most ``pose_tolerance_rad`` (a loaded machine loses or delays
    ``/joint_states`` messages, and a head yawing at 4 rad/s turns 0.4 rad in 0.1 s):

    * interpolation between states ``s0 < t < s1``: accepted when no joint moved by more than
      ``pose_tolerance_rad`` between them (the robot held still across the gap, however wide),
      or when ``s1 - s0 <= 2 max_gap_s`` and the chord's error bound ``|v+ - v-| (s1 - s0) / 4``
      is within the tolerance (``v-``, ``v+``: joint velocities of the neighbouring
      intervals; a velocity change inside the bracket makes the true path leave the chord by
      at most a quarter of the change times the interval);
    * the nearest state at the ends: accepted when the rate of the two nearest states times
      the gap is within the tolerance (with one buffered state there is no evidence of
      motion and the nearest is taken).

    A refused look-up returns the reason; the caller may retry once newer states arrived.
    ``pose_tolerance_rad = inf`` restores the plain time-gap rules."""

    def __init__(self, window_s: float = 2.0, max_items: int = 4000, pose_tolerance_rad: float = 2e-3) -> None:
        if not pose_tolerance_rad >= 0.0:
            raise ValueError(f"pose_tolerance_rad must be >= 0, got {pose_tolerance_rad}")
        self.window_s = float(window_s)
        self.pose_tolerance_rad = float(pose_tolerance_rad)
        self._items: deque[tuple[float, np.ndarray]] = deque(maxlen=int(max_items))

    def __len__(self) -> int:
        return len(self._items)

    def push(self, stamp_s: float, joints: np.ndarray) -> None:
        """Add a state; an older stamp than the newest clears the buffer (time jumped back)."""
        if self._items and stamp_s < self._items[-1][0]:
            self._items.clear()
        self._items.append((float(stamp_s), np.asarray(joints, dtype=float).copy()))
        while self._items[0][0] < stamp_s - self.window_s:
            self._items.popleft()

    def since(self, stamp_s: float) -> list[tuple[float, np.ndarray]]:
        """The buffered ``(stamp, joints)`` states newer than ``stamp_s``, oldest first."""
        stamps = [s for s, _ in self._items]
        return [(s, q.copy()) for s, q in list(self._items)[bisect.bisect_right(stamps, stamp_s):]]

    @property
    def newest_stamp(self) -> float | None:
        return self._items[-1][0] if self._items else None

    def _velocity(self, k: int) -> np.ndarray | None:
        """Joint velocity over the interval between states ``k`` and ``k + 1`` (None outside)."""
        if k < 0 or k + 1 >= len(self._items):
            return None
        (sa, qa), (sb, qb) = self._items[k], self._items[k + 1]
        return (qb - qa) / max(sb - sa, 1e-9)

    def at(self, stamp_s: float, max_gap_s: float) -> tuple[np.ndarray | None, str]:
        """Joint angles at ``stamp_s`` (the rules of the class docstring) and '' -- or None
        and the reason."""
        if not self._items:
            return None, "no /joint_states received yet"
        stamps = [s for s, _ in self._items]
        i = bisect.bisect_left(stamps, stamp_s)
        if i < len(stamps) and stamps[i] == stamp_s:
            return self._items[i][1].copy(), ""
        tol = self.pose_tolerance_rad
        if 0 < i < len(stamps):
            (s0, q0), (s1, q1) = self._items[i - 1], self._items[i]
            moved = float(np.max(np.abs(q1 - q0)))
            if moved > tol:
                if s1 - s0 > 2.0 * max_gap_s:
                    return None, (f"joint states around the image stamp are {s1 - s0:.3f} s apart and the joints "
                                  f"moved up to {moved:.4f} rad between them (pose tolerance {tol:g} rad)")
                v = self._velocity(i - 1)
                before, after = self._velocity(i - 2), self._velocity(i)
                dv = max(float(np.max(np.abs(v - w))) for w in (before, after, v) if w is not None)
                bound = 0.25 * dv * (s1 - s0)
                if bound > tol:
                    return None, (f"joint states around the image stamp are {s1 - s0:.3f} s apart while the joint "
                                  f"velocities change: interpolation may be off by {bound:.4f} rad (pose "
                                  f"tolerance {tol:g} rad)")
            a = (stamp_s - s0) / (s1 - s0)
            return (1.0 - a) * q0 + a * q1, ""
        nearest = 0 if i == 0 else len(stamps) - 1
        gap = abs(stamps[nearest] - stamp_s)
        side = "older" if i == 0 else "newer"
        if gap > max_gap_s:
            return None, (f"image stamp is {gap:.3f} s {side} than the buffered joint states "
                          f"[{stamps[0]:.3f}, {stamps[-1]:.3f}] s (max gap {max_gap_s:g} s)")
        v = self._velocity(0 if i == 0 else len(stamps) - 2)
        drift = float(np.max(np.abs(v))) * gap if v is not None else 0.0
        if drift > tol:
            return None, (f"image stamp is {gap:.3f} s {side} than the buffered joint states while the joints "
                          f"move (a stale pose would be off by up to {drift:.4f} rad; pose tolerance {tol:g} rad)")
        return self._items[nearest][1].copy(), ""


# ----------------------------------------------------------------- R_T_C by forward kinematics
def camera_pose(model: Any, joints: np.ndarray, frame: str) -> np.ndarray:
    """``R_T_C``: world pose (4x4) of the camera frame by forward kinematics, the waist placed
    by :meth:`RobotModel.base_on_feet` (feet fixed on the floor)."""
    q = model.config(joints, model.base_on_feet(joints))
    return np.asarray(model.frame_pose(q, frame).homogeneous)


def same_camera_pose(a: np.ndarray, b: np.ndarray, tol_m: float = 1e-3, tol_rad: float = 1e-3) -> bool:
    """Two camera poses (4x4) within ``tol_m`` and ``tol_rad`` of each other: the camera has not
    moved (the still-view rules of ``voxel_mapper`` and ``marker_localizer``)."""
    cos = (np.trace(b[:3, :3].T @ a[:3, :3]) - 1.0) / 2.0
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])) < tol_m and math.acos(min(1.0, max(-1.0, cos))) < tol_rad


__all__ = [
    "MARKER_KEYS", "transform", "object_pose", "marker_corners", "MarkerSpec", "MarkerTable", "marker_table",
    "load_marker_config", "MarkerDetection", "DetectionResult", "MarkerDetector", "refine_corners_by_edges",
    "solve_marker_pose", "JointStateBuffer", "camera_pose", "same_camera_pose",
]
