"""HPP peer (hpp-python 9.0.2, .venv-peers; LD_LIBRARY_PATH = the cmeel prefix's lib).

Usage: ``python peer_hpp.py WORKDIR {goals|paths|collision}``; last stdout line: JSON.

* goals: hpp-constraints projection (``ConfigProjector``, 60 iterations, threshold 1e-4)
  of each random seed onto: hand frame ``Transformation`` = the WGR sample (6D), both
  soles ``Transformation`` at the stance (6D each), COM xy at COG_approx. The COM is a
  Python ``DifferentiableFunction`` over pinocchio's centre of mass: hpp's own COM
  constraint gave wrong values in 9.0.2. Right hand, then left hand. A new projector per
  sample (its time is counted). Validity checks: by the caller, as for every side.
* paths: ``BiRRTPlanner`` from half-sitting to each goal of the project in the full
  configuration space (37), with the static-stability constraints in the problem's
  config projector (both soles fixed 6D, COM xy inside the support polygon as four
  inequalities, chest/head/grippers and the other arm locked at their values), straight
  steering method, ``ProgressiveProjector`` (step 0.05), ``DiscretizedCollision`` path
  validation (step 0.03), HPP's own collision checking (coal on the robot's capsules as
  URDF spheres+cylinders vs the scene's primitives); time out per goal.
* collision: ``Problem.isConfigValid`` with only ``CollisionValidation`` per configuration
  of ``coll_configs.npz``; verdicts returned for the agreement count.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import emit, guarded, ik_loop, load  # noqa: E402

IK_ITERS = 60
IK_EPS = 1e-4
PATH_TIMEOUT_S = 5.0


def _setup(workdir):
    import pinocchio as pin
    import pyhpp.constraints as K
    import pyhpp.core as C
    from pyhpp.pinocchio import Device, urdf

    P, meta = load(workdir)
    w = Path(workdir)
    robot = Device("hrp2")
    urdf.loadModel(robot, 0, "hrp2", "freeflyer", str(w / "hrp2_capsules.urdf"), str(w / "hrp2_capsules.srdf"),
                   pin.SE3.Identity())
    urdf.loadModel(robot, 0, "env", "anchor", str(w / "scene.urdf"), "", pin.SE3.Identity())
    m = robot.model()
    names = [f"hrp2/{n}" for n in P["joint_names"]]
    if list(m.names[2:]) != names or m.nq != len(P["q_start"]):
        raise RuntimeError("HPP's joint order differs from the project's")
    for j, n in enumerate(P["joint_names"]):
        robot.setJointBounds(f"hrp2/{n}", [float(P["lower"][j]), float(P["upper"][j])])
    robot.setJointBounds("hrp2/root_joint", [-1, 1, -1, 1, 0, 1.5] + [-1.0001, 1.0001] * 4)
    return P, meta, robot, m, pin, K, C


def _eq(K, n):
    cts = K.ComparisonTypes()
    cts[:] = [K.ComparisonType.EqualToZero] * n
    return cts


def _frame_constraint(K, robot, m, pin, name, frame, T):
    fr = m.frames[m.getFrameId("hrp2/" + frame)]
    f = K.Transformation(name, robot, fr.parentJoint, fr.placement, pin.SE3(np.asarray(T)), [True] * 6)
    return K.Implicit(f, _eq(K, 6), [True] * 6)


def _com_function(K, m, pin, target_xy=None, box=None):
    """COM xy - target (2 rows) or, with ``box=(lo, hi)``, (x-lo_x, y-lo_y, hi_x-x, hi_y-y)."""

    class Com(K.DifferentiableFunction):
        def __init__(self):
            super().__init__(m.nq, m.nv, 2 if box is None else 4, "com_xy")
            self.d = m.createData()

        def impl_compute(self, res, q):
            c = pin.centerOfMass(m, self.d, np.asarray(q).reshape(-1), False)[:2]
            res.v = c - target_xy if box is None else np.concatenate([c - box[0], box[1] - c])

        def impl_jacobian(self, J, q):
            Jc = pin.jacobianCenterOfMass(m, self.d, np.asarray(q).reshape(-1), False)[:2]
            return Jc.copy() if box is None else np.vstack([Jc, -Jc])

    return Com()


def goals(workdir) -> dict:
    P, meta, robot, m, pin, K, C = _setup(workdir)
    feet = [_frame_constraint(K, robot, m, pin, "r_sole", "r_sole", P["sole_r"]),
            _frame_constraint(K, robot, m, pin, "l_sole", "l_sole", P["sole_l"])]
    com = K.Implicit(_com_function(K, m, pin, target_xy=P["cog_target_xy"]), _eq(K, 2), [True] * 2)

    def solve_one(q, T, hand):
        cp = C.ConfigProjector(robot, "goal", IK_EPS, IK_ITERS)
        for c in feet + [com, _frame_constraint(K, robot, m, pin, "hand", hand, T)]:
            cp.add(c, 0)
        ok = cp.apply(q)
        return bool(ok), q, IK_ITERS

    ik_loop(P, solve_one, limit=2)  # warm-up
    out = ik_loop(P, solve_one)
    return {"available": True, "version": _version(), **out,
            "method": "hpp-constraints ConfigProjector (hand 6D + soles 6D + Python COM xy function), "
                      f"max {IK_ITERS} it, threshold {IK_EPS}; right hand then left"}


def _version():
    from importlib.metadata import version

    return {"hpp-python": version("hpp-python"), "hpp-core": version("hpp-core")}


def paths(workdir) -> dict:
    P, meta, robot, m, pin, K, C = _setup(workdir)
    if "goals_q" not in P:
        raise RuntimeError("no goals.npz")
    q0 = P["q_start"]
    feet = [_frame_constraint(K, robot, m, pin, "r_sole", "r_sole", P["sole_r"]),
            _frame_constraint(K, robot, m, pin, "l_sole", "l_sole", P["sole_l"])]
    box = (P["support_lo"], P["support_hi"])
    cts = K.ComparisonTypes()
    cts[:] = [K.ComparisonType.Superior] * 4
    com = K.Implicit(_com_function(K, m, pin, box=box), cts, [True] * 4)
    lock_names = meta["locked_joints"]
    idx = {n: i for i, n in enumerate(P["joint_names"])}
    res = {"plans": 0, "success": 0, "time_s": [], "nodes": [], "failures": []}
    problems = {}
    for k, (qg, arm) in enumerate(zip(P["goals_q"], P["goals_arm"])):
        arm_name = {1: "right", 2: "left"}[int(arm)]   # the project's arm codes (codes.ARM_*; no import here)
        if arm_name not in problems:
            other = lock_names["left_arm" if arm_name == "right" else "right_arm"]
            locked = [K.LockedJoint(robot, f"hrp2/{n}", np.array([q0[7 + idx[n]]]))
                      for n in lock_names["fixed"] + other]
            pb = C.Problem(robot)
            pb.clearConfigValidations()
            pb.addConfigValidation("CollisionValidation")
            pb.addConfigValidation("JointBoundValidation")
            pb.addNumericalConstraintsToConfigProjector("stability", feet + [com] + locked)
            pb.steeringMethod = C.Straight(pb)
            pb.pathValidation = C.DiscretizedCollision(robot, 0.03)
            pb.pathProjector = C.ProgressiveProjector(pb.distance(), pb.steeringMethod, 0.05)
            problems[arm_name] = pb
        pb = problems[arm_name]
        pb.resetGoalConfigs()
        pb.initConfig(q0.copy())
        pb.addGoalConfig(np.asarray(qg, float).copy())
        planner = C.BiRRTPlanner(pb)
        planner.timeOut(PATH_TIMEOUT_S)
        res["plans"] += 1
        t0 = time.perf_counter()
        try:
            planner.solve()
            ok = True
        except Exception as e:  # noqa: BLE001 -- HPP raises on failure / time out
            ok = False
            res["failures"].append(f"goal {k}: {str(e)[:120]}")
        dt = time.perf_counter() - t0
        if ok:
            res["success"] += 1
            res["time_s"].append(dt)
            res["nodes"].append(len(planner.roadmap().nodes()))
    return {"available": True, "version": _version(), **res,
            "method": "hpp-core BiRRTPlanner in the full configuration space with static-stability constraints "
                      "(soles fixed 6D, COM xy in the support polygon as inequalities, chest/head/grippers/other "
                      "arm locked), Straight steering, ProgressiveProjector 0.05, DiscretizedCollision 0.03, "
                      f"HPP's collision checking, time out {PATH_TIMEOUT_S} s per goal, no path optimizer"}


def collision(workdir) -> dict:
    P, meta, robot, m, pin, K, C = _setup(workdir)
    Q = np.load(Path(workdir) / "coll_configs.npz")["q"]
    pb = C.Problem(robot)
    pb.clearConfigValidations()
    pb.addConfigValidation("CollisionValidation")
    for q in Q[:20]:
        pb.isConfigValid(q)
    verdict = []
    t0 = time.perf_counter()
    for q in Q:
        verdict.append(bool(pb.isConfigValid(q)[0]))
    dt = time.perf_counter() - t0
    gm = robot.geomModel()
    return {"available": True, "version": _version(), "n_configs": len(Q), "us_per_config": 1e6 * dt / len(Q),
            "valid": verdict, "geoms": int(gm.ngeoms), "collision_pairs": len(gm.collisionPairs),
            "method": "Problem.isConfigValid with CollisionValidation only (coal, robot capsules as URDF "
                      "spheres+cylinders, scene primitives, self pairs of the project's model)"}


if __name__ == "__main__":
    wd, mode = sys.argv[1], sys.argv[2]
    emit(guarded({"goals": goals, "paths": paths, "collision": collision}[mode], wd))
