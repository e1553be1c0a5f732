#!/usr/bin/env python3
"""Benchmark of the measured voxel map (perception/voxel_map.py) and the stereo front end
(perception/stereo.py).

Kanehiro et al. (Sec. II, V) plan on a measured voxel map of 22,753 voxels; Das (003)
asks for about 1 cm depth accuracy at 1 m at 10 Hz. Measured here:

1. **Head scan of the plant scene** (config/scenes/plant.yaml) by the head camera of the
   half-sitting robot (pose by forward kinematics of HEAD_JOINT0/1, feet on the floor): a
   yaw x pitch sweep of ``--yaws`` x ``--pitches`` poses, 640 x 480 pixels, 60 deg
   horizontal field of view (scene_sim's defaults), every second pixel, range noise
   ``sigma = 0.0025 r^2`` m and 2 % dropouts (scene_sim's depth-noise model), ray cast by
   ``Scene.raycast``. For each resolution (0.02, 0.015, 0.01 m):

   * *completeness*: of the ground-truth surface voxels the scans saw -- voxels of
     ``Scene.voxelize`` at the same resolution that contain a noise-free hit above the
     floor band -- the fraction occupied in the map (exactly, and within one voxel);
   * *false occupancy*: the fraction of occupied map voxels farther than one voxel from
     every ground-truth voxel (and the fraction not exactly on one);
   * *integration throughput* [points/s] (``VoxelMap.integrate``: transform, hits and
     3D-DDA clearing of every ray, one numba call per depth map) and the *time to build*
     the whole map from the sweep (sum of the integrate calls; ray casting excluded).
     The resolution whose map is closest to the paper's 22,753 voxels is reported as
     ``paper_sized``.

2. **Stereo depth at 1 m**: a rectified pair of a fronto-parallel textured plane at 1.0 m
   rendered by ``stereo.render_textured_pair`` (analytic ray-plane intersection, 2 x 2
   supersampling, band-limited random texture), 640 x 480, f = 554 px, baseline 0.07 m
   (scene_sim's stereo defaults): median / RMS / 95th percentile depth error of the pixels
   that pass the left-right check, their fraction, and the time per pair (SGBM both ways
   + check + sub-pixel refinement + reprojection); the same without the refinement
   (``sgbm_only``) shows SGBM's integer locking.

3. **Stereo map vs depth map**: when ``humanoid_reach_ros.sim.camera`` (scene_sim's
   renderer) is importable, the plant scene is rendered as a textured stereo pair at each
   pose of a smaller sweep; the stereo clouds build one map, the noise-free depth clouds of
   the same poses another; agreement = fraction of stereo-map voxels within one voxel of
   the depth map (and of the ground truth), and fraction of depth-map voxels the stereo
   map has within one voxel.

Prints a summary and, as the last line, one JSON object.
Run: ``python bench/voxel_map.py`` (from the repository root; ``--quick`` for a smaller sweep).
"""
from __future__ import annotations

import argparse
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
import numba  # noqa: E402

from humanoid_reach_ros.perception.markers import camera_pose  # noqa: E402
from humanoid_reach_ros.perception.stereo import StereoMatcher, StereoParams, render_textured_pair  # noqa: E402
from humanoid_reach_ros.perception.voxel_map import FusionParams, PinholeCamera, VoxelMap  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

PAPER_VOXELS = 22_753
CAMERA_FRAME = "head_camera_optical_frame"
EXTENT = ((-0.5, -1.0, -0.05), (1.5, 1.0, 2.0))
GT_EXTENT = ((-0.5, -1.0, 0.0), (1.5, 1.0, 2.0))
NOISE_PER_M = 0.0025
DROPOUT = 0.02
FLOOR_BAND_M = 0.04


def head_poses(model: RobotModel, yaws: int, pitches: int) -> list[np.ndarray]:
    out = []
    j0, j1 = model.joint_index["HEAD_JOINT0"], model.joint_index["HEAD_JOINT1"]
    for yaw in np.linspace(-0.6, 0.6, yaws):
        for pitch in np.linspace(0.15, 0.75, pitches):
            j = model.half_sitting_joints.copy()
            j[j0], j[j1] = yaw, pitch
            out.append(camera_pose(model, j, CAMERA_FRAME))
    return out


def cast(scene, cam: PinholeCamera, T: np.ndarray, stride: int = 2, max_range: float = 5.0) -> np.ndarray:
    """Unit optical-frame rays (every stride-th pixel) and their ranges (inf: no hit)."""
    d = cam.ray_directions().reshape(cam.height, cam.width, 3)[::stride, ::stride].reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    r = scene.raycast(T[:3, 3], d @ T[:3, :3].T, max_range=max_range)
    return d, r


def keyset(idx: np.ndarray) -> set:
    return set(map(tuple, idx.tolist()))


def near_fraction(a: np.ndarray, b: set, tol: int) -> float:
    """Fraction of integer voxel keys a (N, 3) with a key of set b within tol (Chebyshev)."""
    if len(a) == 0:
        return float("nan")
    r = range(-tol, tol + 1)
    offs = [(i, j, k) for i in r for j in r for k in r]
    hit = 0
    for x, y, z in a.tolist():
        if any((x + i, y + j, z + k) in b for i, j, k in offs):
            hit += 1
    return hit / len(a)


def head_scan(scene, poses, cam, resolutions, rng) -> tuple[list[dict], dict]:
    scans = []
    t0 = time.perf_counter()
    for T in poses:
        d, r = cast(scene, cam, T)
        ok = np.isfinite(r)
        clean = d[ok] * r[ok, None]
        rn = r[ok] + rng.normal(size=ok.sum()) * NOISE_PER_M * r[ok] ** 2
        keep = rng.random(len(rn)) >= DROPOUT
        scans.append((T, clean, d[ok][keep] * rn[keep, None]))
    cast_s = time.perf_counter() - t0
    rows = []
    for h in resolutions:
        m = VoxelMap(FusionParams(resolution_m=h, extent_min_m=EXTENT[0], extent_max_m=EXTENT[1]))
        m.integrate(scans[0][2][:10], scans[0][0])   # compile / load the kernel
        m.clear()
        times, points = [], 0
        for T, _clean, noisy in scans:
            t = time.perf_counter()
            m.integrate(noisy, T)
            times.append(time.perf_counter() - t)
            points += len(noisy)
        occ = m.occupied_indices()
        gt = np.floor(scene.voxelize(h, extent=GT_EXTENT) / h + 1e-9).astype(np.int64)
        gt_set = keyset(gt)
        hits = np.concatenate([clean @ T[:3, :3].T + T[:3, 3] for T, clean, _ in scans])
        seen = np.unique(np.floor(hits[hits[:, 2] > FLOOR_BAND_M] / h).astype(np.int64), axis=0)
        visible = np.array([k for k in seen.tolist() if tuple(k) in gt_set], dtype=np.int64).reshape(-1, 3)
        occ_set = keyset(occ)
        rows.append({
            "resolution_m": h, "occupied_voxels": int(len(occ)), "ground_truth_voxels": int(len(gt)),
            "visible_ground_truth_voxels": int(len(visible)),
            "completeness": near_fraction(visible, occ_set, 0),
            "completeness_within_1": near_fraction(visible, occ_set, 1),
            "false_occupancy_within_1": 1.0 - near_fraction(occ, gt_set, 1),
            "false_occupancy_exact": 1.0 - near_fraction(occ, gt_set, 0),
            "build_time_s": float(sum(times)), "points": int(points),
            "throughput_points_per_s": points / sum(times),
            "integrate_ms_median": 1e3 * float(np.median(times)), "memory_mb": m.nbytes / 1e6,
        })
    return rows, {"poses": len(poses), "raycast_s": cast_s,
                  "points_per_scan": float(np.mean([len(s[2]) for s in scans]))}


def stereo_plane(repeats: int) -> dict:
    pair = render_textured_pair(640, 480, focal_px=554.0, baseline_m=0.07, plane_depth_m=1.0)
    m = StereoMatcher(pair.calibration, StereoParams())
    Z = m.depth(pair.left, pair.right)
    Zs = StereoMatcher(pair.calibration, StereoParams(subpixel=False)).depth(pair.left, pair.right)
    es = Zs[np.isfinite(Zs)] - 1.0
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        m.points(pair.left, pair.right)
        times.append(time.perf_counter() - t)
    valid = np.isfinite(Z)
    err = Z[valid] - 1.0
    return {"depth_m": 1.0, "image": "640x480", "focal_px": 554.0, "baseline_m": 0.07,
            "median_abs_error_m": float(np.median(np.abs(err))), "rms_error_m": float(np.sqrt(np.mean(err ** 2))),
            "p95_abs_error_m": float(np.percentile(np.abs(err), 95)), "mean_error_m": float(np.mean(err)),
            "valid_fraction": float(valid.mean()), "time_per_pair_ms": 1e3 * float(np.median(times)),
            "rate_hz": 1.0 / float(np.median(times)),
            "sgbm_only": {"median_abs_error_m": float(np.median(np.abs(es))), "mean_error_m": float(np.mean(es))}}


def stereo_vs_depth(scene, model: RobotModel, h: float) -> dict:
    try:
        from humanoid_reach_ros.sim import camera as simcam
    except Exception as exc:  # scene_sim's renderer not available
        return {"skipped": f"humanoid_reach_ros.sim.camera not importable: {exc}"}
    poses = head_poses(model, 3, 2)
    cam = simcam.PinholeCamera.from_fov(640, 480, math.radians(60.0))
    style = simcam.RenderStyle(texture_amplitude=0.3)
    B = 0.07
    from humanoid_reach_ros.perception.stereo import StereoCalibration
    K = cam.K
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = P1.copy()
    P2[0, 3] = -cam.fx * B
    cal = StereoCalibration(K, np.zeros(5), np.eye(3), P1, K.copy(), np.zeros(5), np.eye(3), P2,
                            (cam.width, cam.height))
    matcher = StereoMatcher(cal, StereoParams(min_depth_m=0.3, max_depth_m=3.0))
    mk = lambda: VoxelMap(FusionParams(resolution_m=h, extent_min_m=EXTENT[0], extent_max_m=EXTENT[1]))  # noqa: E731
    stereo_map, depth_map = mk(), mk()
    t_stereo = []
    for T in poses:
        TL, TR = simcam.stereo_poses(T, B)
        imgs = []
        for Tc in (TL, TR):
            hits = simcam.cast(scene, cam, Tc, max_range_m=5.0)
            imgs.append(simcam.render_image(scene, hits, None, style, "mono8"))
        t = time.perf_counter()
        pts = matcher.points(imgs[0], imgs[1])
        t_stereo.append(time.perf_counter() - t)
        stereo_map.integrate(pts, TL)
        d, r = cast(scene, PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy), T)
        ok = np.isfinite(r)
        depth_map.integrate(d[ok] * r[ok, None], T)
    s, dm = stereo_map.occupied_indices(), depth_map.occupied_indices()
    gt = keyset(np.floor(scene.voxelize(h, extent=GT_EXTENT) / h + 1e-9).astype(np.int64))
    return {"poses": len(poses), "resolution_m": h, "stereo_voxels": int(len(s)), "depth_voxels": int(len(dm)),
            "stereo_within_1_of_depth": near_fraction(s, keyset(dm), 1),
            "depth_within_1_of_stereo": near_fraction(dm, keyset(s), 1),
            "stereo_within_1_of_ground_truth": near_fraction(s, gt, 1),
            "stereo_time_per_pair_ms": 1e3 * float(np.median(t_stereo)),
            "texture": "sim.camera RenderStyle(texture_amplitude=0.3)", "baseline_m": B}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--yaws", type=int, default=5)
    ap.add_argument("--pitches", type=int, default=4)
    ap.add_argument("--quick", action="store_true", help="3 x 2 poses, resolutions 0.02 and 0.01 only")
    args = ap.parse_args()
    yaws, pitches = (3, 2) if args.quick else (args.yaws, args.pitches)
    resolutions = (0.02, 0.01) if args.quick else (0.02, 0.015, 0.01)
    scene = load_scene("scenes/plant.yaml")
    model = RobotModel()
    cam = PinholeCamera.from_fov(640, 480, math.radians(60.0))
    rng = np.random.default_rng(0)
    poses = head_poses(model, yaws, pitches)
    rows, info = head_scan(scene, poses, cam, resolutions, rng)
    paper = min(rows, key=lambda r: abs(r["occupied_voxels"] - PAPER_VOXELS))
    plane = stereo_plane(5)
    agreement = stereo_vs_depth(scene, model, 0.02)
    result = {
        "bench": "voxel_map",
        "head_scan": {**info, "yaw_steps": yaws, "pitch_steps": pitches, "image": "640x480 (every 2nd pixel)",
                      "noise": f"sigma = {NOISE_PER_M} r^2 m, {DROPOUT:.0%} dropouts", "maps": rows},
        "paper_sized": {"paper_voxels": PAPER_VOXELS, "resolution_m": paper["resolution_m"],
                        "occupied_voxels": paper["occupied_voxels"], "build_time_s": paper["build_time_s"],
                        "throughput_points_per_s": paper["throughput_points_per_s"]},
        "stereo_plane_1m": plane,
        "stereo_vs_depth_map": agreement,
        "platform": {"machine": platform.machine(), "cpus": os.cpu_count(),
                     "load_average_1min": os.getloadavg()[0], "python": platform.python_version(),
                     "numpy": np.__version__, "numba": numba.__version__, "opencv": cv2.__version__},
    }
    print(f"head scan: {info['poses']} poses, {info['points_per_scan']:.0f} points per depth map "
          f"(ray casting {info['raycast_s']:.1f} s, not counted)")
    for r in rows:
        print(f"  h {r['resolution_m']:.3f} m: {r['occupied_voxels']:6d} voxels; completeness {r['completeness']:.3f} "
              f"(within 1 voxel {r['completeness_within_1']:.3f}) of {r['visible_ground_truth_voxels']} visible; "
              f"false occupancy {r['false_occupancy_within_1']:.4f} (not exact {r['false_occupancy_exact']:.3f}); "
              f"built in {r['build_time_s']:.2f} s, {r['throughput_points_per_s'] / 1e6:.2f} M points/s, "
              f"{r['memory_mb']:.0f} MB")
    print(f"paper-sized map ({PAPER_VOXELS} voxels): {paper['occupied_voxels']} voxels at {paper['resolution_m']} m "
          f"built in {paper['build_time_s']:.2f} s")
    print(f"stereo at 1 m: median |error| {1e3 * plane['median_abs_error_m']:.1f} mm, RMS "
          f"{1e3 * plane['rms_error_m']:.1f} mm, p95 {1e3 * plane['p95_abs_error_m']:.1f} mm, "
          f"{plane['valid_fraction']:.0%} valid, {plane['time_per_pair_ms']:.0f} ms/pair ({plane['rate_hz']:.1f} Hz); "
          f"SGBM alone: median {1e3 * plane['sgbm_only']['median_abs_error_m']:.1f} mm")
    if "skipped" in agreement:
        print(f"stereo vs depth map: skipped ({agreement['skipped']})")
    else:
        print(f"stereo vs depth map ({agreement['poses']} poses, {agreement['resolution_m']} m): "
              f"{agreement['stereo_voxels']} vs {agreement['depth_voxels']} voxels; stereo within 1 voxel of depth "
              f"{agreement['stereo_within_1_of_depth']:.3f}, of ground truth "
              f"{agreement['stereo_within_1_of_ground_truth']:.3f}; depth covered by stereo "
              f"{agreement['depth_within_1_of_stereo']:.3f}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
