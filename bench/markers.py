#!/usr/bin/env python3
"""Benchmark of AR-marker localization and of the simulated head camera.

Requirement (Das, 003; docs/paper_map.md): the target position within 1 cm at 1 m, at 10 Hz on
640 x 480 images. The dissertation (004, Sec. 3.2 / 4.5.4) localizes the object by
R_T_O = R_T_C C_T_M M_T_O (eq. 1).

Measured here, on the plant scene's valve marker (config/scenes/plant.yaml: ArUco 7,
DICT_4X4_50, 10 cm, on the hub plate) rendered by ``humanoid_reach_ros.sim.camera`` at
640 x 480, 60 deg horizontal field of view:

* for distances 0.5, 1.0 and 1.5 m and ``VIEWS`` viewpoints each (azimuth up to +-40 deg
  and elevation up to 40 deg off the marker normal, camera roll up to +-20 deg, look-at
  point jittered by up to 5 cm so the marker is not always centred): detection rate, the
  error of the marker position (C_T_M against the ground truth) and of the valve centre
  (eq. 1 with M_T_O from config/marker_localizer.yaml), median / 95th percentile / max;
* detection + PnP time per image (``MarkerDetector.detect`` on a mono8 image: ArUco
  detection with sub-pixel corners + IPPE-square), median and p95 -> localization rate;
* the simulated camera's own cost per 640 x 480 frame: tiled ray cast (1 and 2 threads),
  shading, depth cloud (what bounds scene_sim's rate). On a shared machine these depend on
  the load (reported as ``load_avg_1min``).

Prints a summary and, as the last line, one JSON object.
Run: ``python bench/markers.py`` (from the repository root).
"""
from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402

from humanoid_reach_ros.perception.markers import MarkerDetector, load_marker_config, object_pose  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.sim import camera as C  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

DISTANCES_M = (0.5, 1.0, 1.5)
VIEWS = 12
DETECT_REPEATS = 3
SEED = 5
HEAD_PITCH_RAD = 0.6


def viewpoint(T_wm: np.ndarray, distance_m: float, rng: np.random.Generator) -> np.ndarray:
    """A camera pose looking at the marker from ``distance_m`` at a random angle off its normal."""
    n, up = T_wm[:3, 2], np.array([0.0, 0.0, 1.0])
    side = np.cross(up, n)
    az, el = rng.uniform(-0.7, 0.7), rng.uniform(0.0, 0.7)
    d = math.cos(el) * (math.cos(az) * n + math.sin(az) * side) + math.sin(el) * up
    aim = T_wm[:3, 3] + rng.uniform(-0.05, 0.05, 3)
    T = C.look_at(T_wm[:3, 3] + distance_m * d, aim)
    roll = rng.uniform(-0.35, 0.35)
    Rz = np.array([[math.cos(roll), -math.sin(roll), 0.0], [math.sin(roll), math.cos(roll), 0.0], [0.0, 0.0, 1.0]])
    T[:3, :3] = T[:3, :3] @ Rz
    return T


def stats_mm(errors: list[float]) -> dict[str, float | None]:
    if not errors:
        return {"median_mm": None, "p95_mm": None, "max_mm": None}
    e = 1e3 * np.asarray(errors)
    return {"median_mm": round(float(np.median(e)), 3), "p95_mm": round(float(np.percentile(e, 95)), 3),
            "max_mm": round(float(e.max()), 3)}


def main() -> None:
    scene = load_scene("scenes/plant.yaml")
    table = load_marker_config()
    spec = table.markers[scene.target.aruco.marker_id]
    detector = MarkerDetector(table, max_reprojection_error_px=1.0)
    cam = C.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    marker = C.marker_print_from_scene(scene)
    T_wm, T_wo = scene.target.marker_pose, scene.target.pose
    rng = np.random.default_rng(SEED)

    # warm-up (numba kernels, OpenCV)
    img = C.render_image(scene, C.cast(scene, cam, viewpoint(T_wm, 1.0, rng)), marker, encoding="mono8")
    detector.detect(img, cam.K)

    per_distance, detect_times = {}, []
    for dist in DISTANCES_M:
        marker_err, object_err, reproj, found = [], [], [], 0
        for _ in range(VIEWS):
            T_wc = viewpoint(T_wm, dist, rng)
            img = C.render_image(scene, C.cast(scene, cam, T_wc), marker, encoding="mono8")
            for _ in range(DETECT_REPEATS):
                t0 = time.perf_counter()
                res = detector.detect(img, cam.K)
                detect_times.append(time.perf_counter() - t0)
            dets = [d for d in res.detections if d.marker_id == spec.marker_id]
            if not dets:
                continue
            found += 1
            d = dets[0]
            R_T_M = T_wc @ d.C_T_M
            marker_err.append(float(np.linalg.norm(R_T_M[:3, 3] - T_wm[:3, 3])))
            object_err.append(float(np.linalg.norm(object_pose(T_wc, d.C_T_M, spec.M_T_O)[:3, 3] - T_wo[:3, 3])))
            reproj.append(d.reprojection_error_px)
        per_distance[f"{dist:g}m"] = {
            "views": VIEWS, "detected": found,
            "marker_position_error": stats_mm(marker_err), "valve_centre_error": stats_mm(object_err),
            "reprojection_error_px_median": round(float(np.median(reproj)), 4) if reproj else None,
        }

    # the simulated camera at the head pose that sees the valve
    model = RobotModel()
    j = model.half_sitting_joints.copy()
    j[model.joint_index["HEAD_JOINT1"]] = HEAD_PITCH_RAD
    T_head = np.asarray(model.frame_pose(model.config(j, model.base_on_feet(j)),
                                         "head_camera_optical_frame").homogeneous)
    cast_t, cast2_t, shade_t, depth_t = [], [], [], []
    noise, noise_rng = C.DepthNoise(), np.random.default_rng(0)
    C.cast(scene, cam, T_head, threads=2)
    for _ in range(10):
        t0 = time.perf_counter()
        C.cast(scene, cam, T_head, threads=2)
        cast2_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        hits = C.cast(scene, cam, T_head)
        t1 = time.perf_counter()
        C.render_image(scene, hits, marker)
        t2 = time.perf_counter()
        C.depth_points(hits, noise, noise_rng)
        t3 = time.perf_counter()
        cast_t.append(t1 - t0)
        shade_t.append(t2 - t1)
        depth_t.append(t3 - t2)
    frame_ms = 1e3 * (np.median(cast_t) + np.median(shade_t) + np.median(depth_t))
    frame2_ms = frame_ms + 1e3 * (np.median(cast2_t) - np.median(cast_t))

    det_med, det_p95 = 1e3 * float(np.median(detect_times)), 1e3 * float(np.percentile(detect_times, 95))
    at1 = per_distance["1m"]["valve_centre_error"]["max_mm"]
    result = {
        "bench": "markers",
        "image": {"width": cam.width, "height": cam.height, "hfov_deg": 60.0, "marker_size_m": spec.size_m},
        "per_distance": per_distance,
        "detect_pnp_ms": {"median": round(det_med, 3), "p95": round(det_p95, 3)},
        "localization_rate_hz": round(1e3 / det_med, 1),
        "sim_camera_ms_per_frame": {"cast": round(1e3 * float(np.median(cast_t)), 2),
                                    "cast_2_threads": round(1e3 * float(np.median(cast2_t)), 2),
                                    "shade": round(1e3 * float(np.median(shade_t)), 2),
                                    "depth_cloud": round(1e3 * float(np.median(depth_t)), 2),
                                    "total": round(float(frame_ms), 2)},
        "sim_camera_rate_hz": round(1e3 / frame_ms, 1),
        "sim_camera_rate_hz_2_threads": round(1e3 / frame2_ms, 1),
        "targets": {"valve_error_at_1m_le_10mm": bool(at1 is not None and at1 <= 10.0),
                    "localization_rate_ge_10hz": bool(1e3 / det_med >= 10.0)},
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "load_avg_1min": round(os.getloadavg()[0], 2),
            "python": platform.python_version(),
            "opencv": cv2.__version__,
        },
    }
    for k, v in per_distance.items():
        print(f"{k}: detected {v['detected']}/{v['views']}, marker error {v['marker_position_error']}, "
              f"valve centre error {v['valve_centre_error']}")
    print(f"detection + PnP: median {det_med:.2f} ms, p95 {det_p95:.2f} ms -> {1e3 / det_med:.0f} Hz (target >= 10 Hz)")
    print(f"simulated camera 640x480: cast {result['sim_camera_ms_per_frame']['cast']} ms, shade "
          f"{result['sim_camera_ms_per_frame']['shade']} ms, depth "
          f"{result['sim_camera_ms_per_frame']['depth_cloud']} ms "
          f"-> {result['sim_camera_rate_hz']} Hz; cast on 2 threads "
          f"{result['sim_camera_ms_per_frame']['cast_2_threads']} ms -> {result['sim_camera_rate_hz_2_threads']} Hz")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
