#!/usr/bin/env python3
"""Benchmark: closed-form limb IK (humanoid_reach_ros.kinematics.hand_derived) vs numerical CLIK.

Poses: for each of the four limbs, whole-body configurations with every joint
uniform within its limits and a random base pose; the limb's root and tip poses
come from pinocchio's FK (the same construction as test/test_limb_ik.py).

* closed form, batch 1: one pose per call (LimbIK.solve takes its pure-Python
  single-pose path), N_SINGLE calls per limb (distinct poses), median call time ->
  solves/s;
* closed form, batch 10,000: one call with 10,000 poses, repeated N_REPEAT times,
  median -> solves/s;
* numerical: classical damped-least-squares CLIK with pinocchio on the limb's 6-DOF
  chain (pin.buildReducedModel, every other joint locked; the target is the tip pose
  relative to the root link), one pose at a time in a Python loop, started from the
  half-sitting posture: e = log6(oMtip^-1 oMdes), J = -Jlog6 . frame Jacobian (LOCAL),
  dq = -J^T (J J^T + lambda^2 I)^-1 e, q += dq, until |e| < NUM_EPS or NUM_MAX_IT.
  Batch 1 = median time of single solves; batch 10,000 = mean time per solve over a
  subset of NUM_SUBSET poses per limb, extrapolated (stated in the JSON). Success =
  converged and, after wrapping by 2 pi, within the joint limits (CLIK does not
  enforce limits; from the half-sitting start it often lands on another branch).

Rates are per limb and "avg" = aggregate throughput over the four limbs
(total solves / total time). The last stdout line is one JSON object.
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

try:
    from humanoid_reach_ros.kinematics.registry import LimbIKSet
except ImportError:  # run from a source checkout without PYTHONPATH
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel

SEED = 12345
N_BATCH = 10_000
N_SINGLE = 2_000        # batch-1 closed-form calls per limb
N_REPEAT = 7            # batch-10,000 repetitions per limb
NUM_SINGLE = 200        # numerical batch-1 solves per limb (median)
NUM_SUBSET = 300        # numerical solves per limb timed for the 10,000 extrapolation
NUM_EPS = 1e-10         # |log6 error| to stop (m / rad)
NUM_MAX_IT = 200
NUM_DAMP = 1e-6         # lambda


def sample_poses(robot: RobotModel, limb: str, n: int, rng) -> dict[str, np.ndarray]:
    spec = robot.limbs[limb]
    m, d = robot.model, robot.model.createData()
    fr, ft = robot.frame_id(spec.root), robot.frame_id(spec.tip)
    joints = rng.uniform(robot.lower, robot.upper, (n, robot.n_joints))
    out = {k: np.empty((n, 3)) for k in ("root_p", "tip_p")}
    out.update({k: np.empty((n, 3, 3)) for k in ("root_R", "tip_R")})
    for i in range(n):
        base = pin.SE3(pin.Quaternion(rng.normal(size=4)).normalized().matrix(), rng.uniform(-1, 1, 3))
        pin.framesForwardKinematics(m, d, robot.config(joints[i], base))
        out["root_p"][i], out["root_R"][i] = d.oMf[fr].translation, d.oMf[fr].rotation
        out["tip_p"][i], out["tip_R"][i] = d.oMf[ft].translation, d.oMf[ft].rotation
    return out


class Clik:
    """Damped-least-squares CLIK on the limb's 6-DOF chain (reduced pinocchio model)."""

    def __init__(self, robot: RobotModel, limb: str, q_start: np.ndarray) -> None:
        spec = robot.limbs[limb]
        m = robot.model
        keep = {m.getJointId(j) for j in spec.joints}
        lock = [j for j in range(1, m.njoints) if j not in keep]
        self.model = pin.buildReducedModel(m, lock, robot.config(np.zeros(robot.n_joints)))
        self.data = self.model.createData()
        self.fid = self.model.getFrameId(spec.tip)
        self.root_fid = self.model.getFrameId(spec.root)
        # reduced-model joint order follows the original tree; map to limb order
        self.order = [self.model.getJointId(j) - 1 for j in spec.joints]
        pin.framesForwardKinematics(self.model, self.data, pin.neutral(self.model))
        self.oMroot = self.data.oMf[self.root_fid].copy()   # root link is fixed here
        self.q_start = np.empty(6)
        self.q_start[self.order] = q_start
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self.eye = np.eye(6)

    def solve(self, root: pin.SE3, tip: pin.SE3) -> tuple[np.ndarray, bool, bool, int]:
        model, data, fid = self.model, self.data, self.fid
        oMdes = self.oMroot * root.actInv(tip)
        q = self.q_start.copy()
        lam2 = NUM_DAMP * NUM_DAMP
        converged = False
        it = 0
        for it in range(NUM_MAX_IT + 1):
            pin.framesForwardKinematics(model, data, q)
            iMd = data.oMf[fid].actInv(oMdes)
            err = pin.log6(iMd).vector
            if np.linalg.norm(err) < NUM_EPS:
                converged = True
                break
            if it == NUM_MAX_IT:
                break
            J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
            J = -pin.Jlog6(iMd.inverse()) @ J
            q = q - J.T @ np.linalg.solve(J @ J.T + lam2 * self.eye, err)
        # wrap into the limits' window, then check them
        qw = self.lower + np.mod(q - self.lower, 2 * np.pi)
        in_limits = bool(np.all(qw <= self.upper + 1e-10))
        return qw[self.order], converged and in_limits, converged, it


def main() -> None:
    rng = np.random.default_rng(SEED)
    robot = RobotModel()
    iks = LimbIKSet(robot)
    res: dict[str, dict] = {}
    for limb in iks.names:
        ik = iks[limb]
        P = sample_poses(robot, limb, N_BATCH, rng)
        args = (P["root_p"], P["root_R"], P["tip_p"], P["tip_R"])
        ik.solve(*(a[:10] for a in args))  # warm-up
        # ---------------- closed form, batch 1
        times = []
        for i in range(N_SINGLE):
            rp, rR, tp, tR = (a[i] for a in args)
            t0 = time.perf_counter()
            ik.solve(rp, rR, tp, tR)
            times.append(time.perf_counter() - t0)
        cf1 = statistics.median(times)
        # ---------------- closed form, batch 10,000
        times = []
        for _ in range(N_REPEAT):
            t0 = time.perf_counter()
            sol = ik.solve(*args)
            times.append(time.perf_counter() - t0)
        cfN = statistics.median(times)
        p, R = ik.fk(P["root_p"], P["root_R"], sol.q)
        cf_err = float(np.nanmax(np.linalg.norm(p - P["tip_p"], axis=1)))
        # ---------------- numerical CLIK
        clik = Clik(robot, limb, ik.q_default)
        roots = [pin.SE3(P["root_R"][i], P["root_p"][i]) for i in range(NUM_SUBSET)]
        tips = [pin.SE3(P["tip_R"][i], P["tip_p"][i]) for i in range(NUM_SUBSET)]
        num_t, num_ok, num_conv, num_it, num_err = [], [], [], [], []
        for i in range(NUM_SUBSET):
            t0 = time.perf_counter()
            q, ok, conv, it = clik.solve(roots[i], tips[i])
            num_t.append(time.perf_counter() - t0)
            num_ok.append(ok)
            num_conv.append(conv)
            num_it.append(it)
            if ok:
                pp, _ = ik.fk(P["root_p"][i], P["root_R"][i], q)
                num_err.append(float(np.linalg.norm(pp[0] - P["tip_p"][i])))
        num1 = statistics.median(num_t[:NUM_SINGLE])
        numN = statistics.fmean(num_t)
        res[limb] = {
            "closed_form_batch1_per_s": 1.0 / cf1,
            "closed_form_batch10000_per_s": N_BATCH / cfN,
            "closed_form_success_rate": float(sol.ok.mean()),
            "closed_form_max_pos_err_m": cf_err,
            "numerical_batch1_per_s": 1.0 / num1,
            "numerical_batch10000_per_s_extrapolated": 1.0 / numN,
            "numerical_success_rate": float(np.mean(num_ok)),
            "numerical_converged_rate_ignoring_limits": float(np.mean(num_conv)),
            "numerical_mean_iterations": float(np.mean(num_it)),
            "numerical_mean_iterations_successful": float(np.mean(np.array(num_it)[np.array(num_ok)]))
            if any(num_ok) else None,
            "numerical_max_pos_err_m": max(num_err) if num_err else None,
            "_t": (cf1, cfN / N_BATCH, num1, numN, num_it, num_ok, num_conv),
        }
        r = res[limb]
        print(f"{limb:10s} closed form: batch1 {r['closed_form_batch1_per_s']:9.0f}/s  "
              f"batch10k {r['closed_form_batch10000_per_s']:10.0f}/s  ok {r['closed_form_success_rate']:.4f} | "
              f"CLIK: batch1 {r['numerical_batch1_per_s']:7.0f}/s  10k(extrap) "
              f"{r['numerical_batch10000_per_s_extrapolated']:7.0f}/s  ok {r['numerical_success_rate']:.3f} "
              f"(conv {r['numerical_converged_rate_ignoring_limits']:.3f})  "
              f"mean it {r['numerical_mean_iterations']:.1f}")

    limbs = list(res)
    t = {k: [res[limb]["_t"][j] for limb in limbs] for j, k in enumerate(("cf1", "cfN", "num1", "numN"))}
    avg = {
        "closed_form_batch1_per_s": len(limbs) / sum(t["cf1"]),
        "closed_form_batch10000_per_s": len(limbs) / sum(t["cfN"]),
        "numerical_batch1_per_s": len(limbs) / sum(t["num1"]),
        "numerical_batch10000_per_s_extrapolated": len(limbs) / sum(t["numN"]),
    }
    all_it = np.concatenate([res[limb]["_t"][4] for limb in limbs])
    all_ok = np.concatenate([res[limb]["_t"][5] for limb in limbs])
    avg["ratio_batch1_analytic_over_numerical"] = avg["closed_form_batch1_per_s"] / avg["numerical_batch1_per_s"]
    avg["ratio_batch10000_analytic_over_numerical"] = (
        avg["closed_form_batch10000_per_s"] / avg["numerical_batch10000_per_s_extrapolated"])
    avg["numerical_success_rate"] = float(all_ok.mean())
    avg["numerical_converged_rate_ignoring_limits"] = float(
        np.concatenate([res[limb]["_t"][6] for limb in limbs]).mean())
    avg["numerical_mean_iterations"] = float(all_it.mean())
    avg["numerical_mean_iterations_successful"] = float(all_it[all_ok].mean()) if all_ok.any() else None
    for limb in limbs:
        del res[limb]["_t"]
        res[limb]["ratio_batch1_analytic_over_numerical"] = (
            res[limb]["closed_form_batch1_per_s"] / res[limb]["numerical_batch1_per_s"])
        res[limb]["ratio_batch10000_analytic_over_numerical"] = (
            res[limb]["closed_form_batch10000_per_s"] / res[limb]["numerical_batch10000_per_s_extrapolated"])
    print(f"avg (aggregate over 4 limbs): closed form batch1 {avg['closed_form_batch1_per_s']:.0f}/s, "
          f"batch10k {avg['closed_form_batch10000_per_s']:.0f}/s; CLIK batch1 {avg['numerical_batch1_per_s']:.0f}/s, "
          f"10k {avg['numerical_batch10000_per_s_extrapolated']:.0f}/s; ratio batch1 "
          f"{avg['ratio_batch1_analytic_over_numerical']:.1f}x, batch10k "
          f"{avg['ratio_batch10000_analytic_over_numerical']:.0f}x")
    out = {
        "bench": "limb_ik",
        "units": "solves per second",
        "avg_definition": "aggregate over the four limbs: 4 / sum of per-limb time per solve",
        "poses": "joints uniform within limits, random base pose; root and tip poses from pinocchio FK",
        "closed_form_batch1": f"median of {N_SINGLE} single-pose calls per limb",
        "closed_form_batch10000": f"median of {N_REPEAT} calls with {N_BATCH} poses per limb",
        "numerical_method": (f"pinocchio DLS CLIK on the reduced 6-DOF limb model, lambda={NUM_DAMP}, "
                             f"full step, |log6| < {NUM_EPS}, max {NUM_MAX_IT} iterations, start at "
                             "half-sitting, Python loop, success = converged and within joint limits"),
        "numerical_batch1": f"median over {NUM_SINGLE} single solves per limb",
        "numerical_batch10000": (f"extrapolated: mean time per solve over {NUM_SUBSET} poses per limb "
                                 f"(not all {N_BATCH})"),
        "avg": avg,
        "per_limb": res,
        "machine": {
            "processor": platform.processor(),
            "machine": platform.machine(),
            "node": platform.node(),
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "pinocchio": pin.__version__,
        },
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
