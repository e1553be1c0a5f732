"""placo peer (placo 0.10.2, own venv .venv-placo: it pins pinocchio 3.8).

Usage: ``python peer_placo.py WORKDIR``; last stdout line: JSON (candidates; the caller
runs the common validity checks -- this venv has no project). ``KinematicsSolver`` with
hard frame tasks for both soles at the stance, a soft frame task (weight 1) for the hand
at the WGR sample and a CoM task on x, y at COG_approx, joint limits enabled; one
``solve(True)`` per iteration, at most ``IK_ITERS``, converged when every error is below
``IK_EPS``. Right hand, then left hand.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import emit, guarded, ik_loop, load  # noqa: E402

IK_ITERS = 60
IK_EPS = 1e-4


def run(workdir) -> dict:
    import pinocchio as pin
    import placo

    P, meta = load(workdir)
    robot = placo.RobotWrapper(meta["urdf"], placo.Flags.ignore_collisions)
    model = robot.model
    if list(model.names[2:]) != list(P["joint_names"]):
        raise RuntimeError("joint order differs from the project's")
    data = model.createData()
    soles = {"r_sole": P["sole_r"], "l_sole": P["sole_l"]}
    cog = P["cog_target_xy"]
    fids = {f: model.getFrameId(f) for f in ("r_sole", "l_sole", "r_hand_ee", "l_hand_ee")}

    def errors(q, hand, T):
        pin.framesForwardKinematics(model, data, q)
        e = [pin.log6(data.oMf[fids[f]].actInv(pin.SE3(M))).vector for f, M in soles.items()]
        e.append(pin.log6(data.oMf[fids[hand]].actInv(pin.SE3(T))).vector)
        c = pin.centerOfMass(model, data, q, False)[:2] - cog
        return max(float(np.abs(np.concatenate(e)).max()), float(np.abs(c).max()))

    def solve_one(q, T, hand):
        solver = placo.KinematicsSolver(robot)
        solver.enable_joint_limits(True)
        solver.enable_velocity_limits(False)
        for f, M in soles.items():
            solver.add_frame_task(f, M).configure(f, "soft", 1.0, 1.0)
        solver.add_frame_task(hand, np.asarray(T)).configure("hand", "soft", 1.0, 1.0)
        ct = solver.add_com_task(np.array([cog[0], cog[1], 0.0]))
        ct.mask.set_axises("xy")
        ct.configure("com", "soft", 1.0)
        robot.state.q = q.copy()
        robot.update_kinematics()
        for it in range(1, IK_ITERS + 1):
            try:
                solver.solve(True)
            except RuntimeError:      # QPError: infeasible (joint limits): not converged
                return False, np.array(robot.state.q), it
            robot.update_kinematics()
            qq = robot.state.q
            if errors(qq, hand, T) < IK_EPS:
                return True, np.array(qq), it
        return False, np.array(robot.state.q), IK_ITERS

    ik_loop(P, solve_one, limit=2)  # warm-up
    out = ik_loop(P, solve_one)
    from importlib.metadata import version

    return {"available": True, "version": {"placo": version("placo"), "pin": version("pin")}, **out,
            "method": f"placo KinematicsSolver (soles and hand soft w=1, CoM xy soft w=1, joint limits), "
                      f"max {IK_ITERS} it, eps {IK_EPS}; right hand then left"}


if __name__ == "__main__":
    emit(guarded(run, sys.argv[1]))
