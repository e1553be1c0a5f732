#!/usr/bin/env python3
"""Benchmark: the compiled general closed-form IK (humanoid_reach_ros.kinematics.general_ik_compiled)
against its numpy reference (kinematics/general_ik.py), one pose per call, with HRP-2's
hand-derived compiled arm kernel (reach/fast_arms.CompiledArmIK) as the yardstick.

Limbs: Talos's right arm (7R: RedundantLimbIK, 16 first-joint values) and right leg as a
GeneralLimbIK chain (6R, reversed form; in the limb set Talos's legs get the hand-derived
compiled leg kernel, this measures the general one on a real leg); HRP-2's right arm
through CompiledArmIK.solve and, for comparison, through the general compiled kernel.

Poses: joints uniform within the limits, the tip pose from the chain's FK relative to the
limb's root (the same construction as test/test_general_ik_compiled.py). Reference joints:
the default (half-sitting clipped into the limits, what GeneralLimb passes when the caller
gives none); for the 7R arm also the drawn joints ("tracking": a reference next to the
answer, as in a control loop, where the compiled search stops early).

Per limb and solver: the median wall time of one ``solve`` call (N = 1, the numpy classes'
API) over ``--calls`` distinct poses after a warm-up, the compiled twin's ``solve_one`` (the
cheapest call, as CompiledArmIK.solve) and the compiled batch kernel's time per pose over
all poses in one call. The numpy and compiled answers of the timed poses are compared (ok
equal, max |dq|). Last stdout line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from humanoid_reach_ros.testing.machine import describe as describe_machine  # noqa: E402
from humanoid_reach_ros.kinematics.hand_derived_compiled import CompiledArmIK  # noqa: E402
from humanoid_reach_ros.kinematics import general_ik_compiled  # noqa: E402
from humanoid_reach_ros.kinematics.general_ik import Chain6, GeneralLimbIK, RedundantLimbIK  # noqa: E402
from humanoid_reach_ros.kinematics.general_ik_compiled import compiled_general_ik  # noqa: E402
from humanoid_reach_ros.kinematics.registry import LimbIKSet  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.kinematics.numerical_ik import NumericalLimbIK  # noqa: E402
from humanoid_reach_ros.kinematics import numerical_ik  # noqa: E402

G1_URDF = "share/example-robot-data/robots/g1_description/urdf/g1_29dof_rev_1_0.urdf"
G1_JOINTS = {
    "right_leg": ("pelvis", [f"right_{j}_joint" for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch",
                                                           "ankle_roll")], "right_ankle_roll_link"),
    "right_arm": ("torso_link", [f"right_{j}_joint" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw",
                                                              "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw")],
                  "right_wrist_yaw_link"),
}


def limb_chain(robot: RobotModel, limb: str):
    """The limb's Chain6 and default reference, as GeneralLimb builds them."""
    spec = robot.limbs[limb]
    chain = Chain6.from_model(robot, spec.root, spec.joints, spec.tip)
    q_default = np.clip(np.asarray(robot.half_sitting_joints)[list(spec.joint_index)], chain.lower, chain.upper)
    return chain, q_default


def median_us(solve, args: list[tuple]) -> tuple[float, list]:
    """Median wall time [us] of ``solve(*a)`` over ``args`` (rows prepared beforehand: only the
    call is timed), and the answers."""
    times, answers = [], []
    clock = time.perf_counter
    for a in args:
        t0 = clock()
        r = solve(*a)
        times.append(clock() - t0)
        answers.append(r)
    return 1e6 * statistics.median(times), answers


def measure(name: str, chain, q_default, calls: int, numpy_calls: int, rng, refs=("default",)) -> dict:
    """numpy reference vs compiled twin on one chain, per reference kind."""
    nj = len(chain.axes)
    numpy_ik = RedundantLimbIK(chain, q_default) if nj == 7 else GeneralLimbIK(chain, q_default)
    fast = compiled_general_ik(chain, q_default)
    n = max(calls, numpy_calls)
    q = rng.uniform(chain.lower, chain.upper, (n, nj))
    P, R = chain.fk(q)
    out = {}
    for kind in refs:
        out.update(measure_refs(name if kind == "default" else f"{name}_{kind}", numpy_ik, fast, P, R,
                                None if kind == "default" else q, calls, numpy_calls))
    return out


def measure_refs(key: str, numpy_ik, fast, P, R, Q, calls: int, numpy_calls: int) -> dict:
    """One chain, one kind of reference joints ``Q`` (None: the default)."""
    rows = [(P[i], R[i], None if Q is None else Q[i]) for i in range(len(P))]
    for solve in (numpy_ik.solve, fast.solve, fast.solve_one):   # warm-up
        solve(*rows[0])
    t_np, answers = median_us(numpy_ik.solve, rows[:numpy_calls])
    t_c, _ = median_us(fast.solve, rows[:calls])
    t_one, _ = median_us(fast.solve_one, rows[:calls])
    t0 = time.perf_counter()
    batch = fast.solve(P[:calls], R[:calls], None if Q is None else Q[:calls])
    t_batch = 1e6 * (time.perf_counter() - t0) / calls
    ok_np = np.array([a.ok[0] for a in answers])
    q_np = np.array([a.q[0] for a in answers])
    cmp = fast.solve(P[:numpy_calls], R[:numpy_calls], None if Q is None else Q[:numpy_calls])
    both = ok_np & cmp.ok
    out = {
        f"{key}_us_numpy": t_np, f"{key}_us_compiled": t_c, f"{key}_us_compiled_one": t_one,
        f"{key}_us_compiled_batch_per_pose": t_batch,
        f"{key}_ok_rate": float(batch.ok.mean()),
        f"{key}_agree_ok": bool(np.array_equal(ok_np, cmp.ok)),
        f"{key}_agree_max_dq": float(np.abs(q_np[both] - cmp.q[both]).max(initial=0.0)),
    }
    print(f"{key:22s} numpy {t_np:10.1f} us | compiled solve {t_c:7.2f} us, solve_one {t_one:7.2f} us, "
          f"batch {t_batch:7.2f} us/pose | ok {batch.ok.mean():.3f} | numpy == compiled: ok "
          f"{out[f'{key}_agree_ok']}, max |dq| {out[f'{key}_agree_max_dq']:.1e}")
    return out


class _G1:
    """The Unitree G1 from example-robot-data's URDF (free-flyer root), with what
    Chain6.from_model reads of a RobotModel (``model``, ``joint_index``, ``lower``, ``upper``)."""

    def __init__(self) -> None:
        import cmeel
        import pinocchio as pin

        urdf = Path(cmeel.__path__[0]).parent / "cmeel.prefix" / G1_URDF
        self.model = m = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
        self.joint_index = {m.names[j]: m.joints[j].idx_q - 7 for j in range(2, m.njoints)}
        self.lower, self.upper = m.lowerPositionLimit[7:].copy(), m.upperPositionLimit[7:].copy()

    def chain(self, limb: str):
        root, joints, tip = G1_JOINTS[limb]
        c = Chain6.from_model(self, root, joints, tip)
        return c, np.clip(np.zeros(len(joints)), c.lower, c.upper)


def measure_numerical(name: str, chain, q_default, calls: int, rng) -> dict:
    """NumericalLimbIK on one chain: default reference, tracking reference, unreachable poses."""
    nj = len(chain.axes)
    ik = NumericalLimbIK(chain, q_default)
    q = rng.uniform(chain.lower, chain.upper, (calls, nj))
    P, R = chain.fk(q)
    near = q + rng.uniform(-0.05, 0.05, q.shape)
    out = {}
    for kind, refs in (("default", None), ("tracking", near)):
        key = name if kind == "default" else f"{name}_{kind}"
        rows = [(P[i], R[i], None if refs is None else refs[i]) for i in range(calls)]
        ik.solve(*rows[0])
        ik.solve_one(*rows[0])
        t_s, answers = median_us(ik.solve, rows)
        t_one, _ = median_us(ik.solve_one, rows)
        ok = np.array([a.ok[0] for a in answers])
        qa = np.array([a.q[0] for a in answers])
        p2, R2 = chain.fk(np.nan_to_num(qa))
        err = max(float(np.abs(p2 - P)[ok].max(initial=0.0)), float(np.abs(R2 - R)[ok].max(initial=0.0)))
        dq = np.abs(qa - q).max(axis=1)[ok]
        out.update({f"{key}_us_numerical": t_s, f"{key}_us_numerical_one": t_one, f"{key}_ok_rate": float(ok.mean()),
                    f"{key}_max_fk_err": err, f"{key}_median_dq_to_drawn": float(np.median(dq))})
        print(f"{key:22s} numerical solve {t_s:8.2f} us, solve_one {t_one:8.2f} us | ok {ok.mean():.3f} | "
              f"max FK error {err:.1e} | median max|q - drawn| {np.median(dq):.3f} rad")
    # poses 0.5 m beyond the reach bound (the last joint's origin that far from the first's)
    m = min(calls, 200)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    bound = float(np.sum(np.linalg.norm(chain.t[1:], axis=1)))
    Pf = chain.t[0] + (bound + 0.5) * d + R[:m] @ (chain.Re.T @ chain.te)
    t_far, answers = median_us(ik.solve_one, [(Pf[i], R[i]) for i in range(m)])
    out[f"{name}_unreachable_us_numerical_one"] = t_far
    ok_far = float(np.mean([a[0] for a in answers]))
    print(f"{name + '_unreachable':22s} numerical solve_one {t_far:8.2f} us (ok {ok_far:.3f})")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=2000, help="compiled calls per limb (distinct poses)")
    parser.add_argument("--numpy-calls", type=int, default=2000, help="numpy reference calls per limb")
    parser.add_argument("--seed", type=int, default=12345)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    general_ik_compiled.warm_up()
    numerical_ik.warm_up()
    warm_s = time.perf_counter() - t0

    talos, hrp2 = RobotModel("talos"), RobotModel("hrp2")
    res = {}
    res.update(measure("talos_arm", *limb_chain(talos, "right_arm"), args.calls, args.numpy_calls, rng,
                       refs=("default", "tracking")))
    res.update(measure("talos_leg", *limb_chain(talos, "right_leg"), args.calls, args.numpy_calls, rng))

    # yardstick: HRP-2's hand-derived arm kernel, and the general compiled kernel on the same arm
    arm = LimbIKSet(hrp2)["right_arm"]
    yard = CompiledArmIK(arm)
    q = rng.uniform(arm.lower, arm.upper, (args.calls, 6))
    z, eye = np.zeros(3), np.eye(3)
    P, R = arm.fk(z, eye, q)
    ref = arm.q_default.copy()
    rows = [(z, eye, P[i], R[i], ref) for i in range(args.calls)]
    yard.solve(*rows[0])
    t_hrp2, answers = median_us(yard.solve, rows)
    chain, q_default = limb_chain(hrp2, "right_arm")
    gen = compiled_general_ik(chain, q_default)
    rows = [(P[i], R[i], q_default) for i in range(args.calls)]
    gen.solve_one(*rows[0])
    t_gen, _ = median_us(gen.solve_one, rows)
    ok_yard = np.array([reason == 0 for reason, _ in answers])
    ok_gen = gen.solve(P, R).ok
    print(f"{'hrp2_arm':22s} CompiledArmIK.solve {t_hrp2:7.2f} us (ok {ok_yard.mean():.3f}) | general compiled "
          f"solve_one {t_gen:7.2f} us (ok {ok_gen.mean():.3f}; the same q_ref)")
    res.update({
        "hrp2_arm_us_compiled": t_hrp2, "hrp2_arm_general_us_compiled_one": t_gen,
        "talos_arm_vs_hrp2_ratio": res["talos_arm_us_compiled"] / t_hrp2,
        "talos_arm_one_vs_hrp2_ratio": res["talos_arm_us_compiled_one"] / t_hrp2,
        "talos_arm_tracking_vs_hrp2_ratio": res["talos_arm_tracking_us_compiled"] / t_hrp2,
        "talos_leg_vs_hrp2_ratio": res["talos_leg_us_compiled"] / t_hrp2,
        "speedup_arm": res["talos_arm_us_numpy"] / res["talos_arm_us_compiled"],
        "speedup_arm_tracking": res["talos_arm_tracking_us_numpy"] / res["talos_arm_tracking_us_compiled"],
        "speedup_leg": res["talos_leg_us_numpy"] / res["talos_leg_us_compiled"],
    })
    # the numerical solver on the Unitree G1 (no closed form), against the same yardstick
    g1 = _G1()
    res.update(measure_numerical("g1_arm", *g1.chain("right_arm"), args.calls, rng))
    res.update(measure_numerical("g1_leg", *g1.chain("right_leg"), args.calls, rng))
    for key in ("g1_arm", "g1_arm_tracking", "g1_leg", "g1_leg_tracking"):
        res[f"{key}_one_vs_hrp2_ratio"] = res[f"{key}_us_numerical_one"] / t_hrp2
    print("G1 numerical solve_one / HRP-2 arm CompiledArmIK.solve: " + ", ".join(
        f"{k} {res[f'{k}_one_vs_hrp2_ratio']:.1f}" for k in ("g1_arm", "g1_arm_tracking", "g1_leg", "g1_leg_tracking")))
    print(f"speedup (numpy / compiled solve): arm {res['speedup_arm']:.0f}x, arm tracking "
          f"{res['speedup_arm_tracking']:.0f}x, leg {res['speedup_leg']:.0f}x; Talos arm / HRP-2 arm "
          f"{res['talos_arm_vs_hrp2_ratio']:.2f} (solve_one {res['talos_arm_one_vs_hrp2_ratio']:.2f}, tracking "
          f"{res['talos_arm_tracking_vs_hrp2_ratio']:.2f})")
    out = {
        "bench": "general_ik",
        "units": "microseconds per call (median), one pose per call",
        "poses": ("joints uniform within the limits, tip pose from the chain's FK relative to the limb's root; "
                  f"seed {args.seed}"),
        "calls": {"compiled": args.calls, "numpy": args.numpy_calls},
        "reference_joints": "default: half-sitting clipped into the limits; tracking: the drawn joints",
        "limbs": {"talos_arm": "talos right_arm, 7R, RedundantLimbIK samples=16",
                  "talos_leg": "talos right_leg as a GeneralLimbIK chain (6R, reversed form)",
                  "hrp2_arm": "hrp2 right_arm: CompiledArmIK.solve (hand-derived), and the general compiled kernel",
                  "g1_arm": "Unitree G1 right arm (URDF g1_29dof_rev_1_0), 7R: NumericalLimbIK",
                  "g1_leg": "Unitree G1 right leg, 6R: NumericalLimbIK"},
        "numerical_reference_joints": ("default: zero joints clipped into the limits; tracking: the drawn joints "
                                       "+ uniform(-0.05, 0.05) rad; unreachable: 0.5 m beyond the reach bound"),
        "warm_up_s": warm_s,
        **res,
        "machine": {"description": describe_machine(), "load_avg_1m": round(os.getloadavg()[0], 2)},
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
