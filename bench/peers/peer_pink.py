"""pink peer (pin-pink 4.4.0 + daqp, .venv-peers): differential IK projection of the seeds.

Usage: ``python peer_pink.py WORKDIR``; last stdout line: JSON (candidates; the caller
runs the common validity checks). Tasks (all cost 1): hand ``FrameTask`` at the WGR
sample, both soles ``FrameTask`` at the stance, ``ComTask`` on x, y at COG_approx
(z cost 0). Configuration limits on (pink's default); ``dt`` = 1 (full steps), at most
``IK_ITERS`` iterations, converged when every error is below ``IK_EPS``. Right hand,
then left hand.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import emit, guarded, ik_loop, load  # noqa: E402

IK_ITERS = 60
IK_EPS = 1e-4
DT = 1.0


def run(workdir) -> dict:
    import pinocchio as pin
    import pink
    from pink import solve_ik
    from pink.tasks import ComTask, FrameTask

    P, meta = load(workdir)
    model = pin.buildModelFromUrdf(meta["urdf"], pin.JointModelFreeFlyer())
    data = model.createData()
    if list(model.names[2:]) != list(P["joint_names"]):
        raise RuntimeError("joint order differs from the project's")
    soles = {"r_sole": pin.SE3(P["sole_r"]), "l_sole": pin.SE3(P["sole_l"])}
    feet = {f: FrameTask(f, position_cost=1.0, orientation_cost=1.0) for f in soles}
    for f, T in soles.items():
        feet[f].set_target(T)
    com = ComTask(cost=np.array([1.0, 1.0, 0.0]))
    hands = {h: FrameTask(h, position_cost=1.0, orientation_cost=1.0) for h in ("r_hand_ee", "l_hand_ee")}
    fids = {f: model.getFrameId(f) for f in list(soles) + list(hands)}
    cog = P["cog_target_xy"]

    def errors(q, hand, T):
        pin.framesForwardKinematics(model, data, q)
        e = [pin.log6(data.oMf[fids[f]].actInv(soles[f])).vector for f in soles]
        e.append(pin.log6(data.oMf[fids[hand]].actInv(T)).vector)
        c = pin.centerOfMass(model, data, q, False)[:2] - cog
        return max(float(np.abs(np.concatenate(e)).max()), float(np.abs(c).max()))

    def solve_one(q, T, hand):
        Tse = pin.SE3(np.asarray(T))
        hands[hand].set_target(Tse)
        conf = pink.Configuration(model, data, q)
        com.set_target(np.array([cog[0], cog[1], 0.0]))
        tasks = [hands[hand], *feet.values(), com]
        for it in range(1, IK_ITERS + 1):
            v = solve_ik(conf, tasks, DT, solver="daqp", safety_break=False)
            conf.integrate_inplace(v, DT)
            if errors(conf.q, hand, Tse) < IK_EPS:
                return True, conf.q.copy(), it
        return False, conf.q.copy(), IK_ITERS

    ik_loop(P, solve_one, limit=2)  # warm-up
    out = ik_loop(P, solve_one)
    from importlib.metadata import version

    return {"available": True, "version": {"pin-pink": version("pin-pink"), "daqp": version("daqp")}, **out,
            "method": f"pink solve_ik (daqp), hand/soles FrameTask + ComTask xy, dt {DT}, max {IK_ITERS} it, "
                      f"eps {IK_EPS}; right hand then left"}


if __name__ == "__main__":
    emit(guarded(run, sys.argv[1]))
