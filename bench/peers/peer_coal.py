"""coal peer (coal 3.0.3, .venv-peers or the project venv): collision check per configuration.

Usage: ``python peer_coal.py WORKDIR``; last stdout line: JSON.

The robot's own shapes (config/robots/hrp2/collision.yaml: ``coal.Capsule`` /
``coal.Sphere`` with the padded radii) against the scene's primitives (no floor, no
valve: ``coal.Box`` / ``coal.Cylinder`` / ``coal.Sphere``), exact geometry, and the
project's 120 self-collision pairs. Per configuration: pinocchio frame kinematics, the
shapes' transforms set, robot vs scene through two ``DynamicAABBTreeCollisionManager``
(one ``collide`` call), then the self pairs by ``coal.collide`` until the first hit.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import emit, guarded  # noqa: E402


class CoalChecker:
    def __init__(self, prob) -> None:
        import coal
        import pinocchio as pin

        self.coal, self.pin = coal, pin
        self.robot = prob.robot
        self.m = prob.robot.model
        self.d = self.m.createData()
        cm = prob.planner.collision_model
        self.frame_of = [int(cm.frame_ids[int(cm.shape_link[s])]) for s in range(cm.n_shapes)]
        self.local = []
        self.objs = []
        for s in range(cm.n_shapes):
            p0, p1, r = np.asarray(cm.p0_local[s]), np.asarray(cm.p1_local[s]), float(cm.radii[s])
            L = float(np.linalg.norm(p1 - p0))
            if L < 1e-9:
                geom, R = coal.Sphere(r), np.eye(3)
            else:
                geom = coal.Capsule(r, L)
                R = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), (p1 - p0) / L).toRotationMatrix()
            self.local.append(pin.SE3(R, 0.5 * (p0 + p1)))
            self.objs.append(coal.CollisionObject(geom, coal.Transform3s()))
        self.pairs = [(int(i), int(j)) for i, j in cm.pair_index]
        self.env = []
        for p in prob.scene.select(include_floor=False, exclude_groups=("valve",)):
            if p.kind == "box":
                from humanoid_reach_ros.sim.scene import rpy_to_matrix

                g, T = coal.Box(*np.asarray(p.size, float)), pin.SE3(rpy_to_matrix(p.rpy), np.asarray(p.center, float))
            elif p.kind == "cylinder":
                a, b = np.asarray(p.p0, float), np.asarray(p.p1, float)
                L = float(np.linalg.norm(b - a))
                R = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), (b - a) / L).toRotationMatrix()
                g, T = coal.Cylinder(float(p.radius), L), pin.SE3(R, 0.5 * (a + b))
            elif p.kind == "sphere":
                g, T = coal.Sphere(float(p.radius)), pin.SE3(np.eye(3), np.asarray(p.center, float))
            else:
                raise ValueError(f"no coal shape for {p.kind}")
            self.env.append(coal.CollisionObject(g, coal.Transform3s(T.rotation, T.translation)))
        self.env_mgr = coal.DynamicAABBTreeCollisionManager()
        for o in self.env:
            self.env_mgr.registerObject(o)
        self.env_mgr.setup()
        self.rob_mgr = coal.DynamicAABBTreeCollisionManager()
        for o in self.objs:
            self.rob_mgr.registerObject(o)
        self.rob_mgr.setup()
        self.req = coal.CollisionRequest()
        self.res = coal.CollisionResult()

    def check(self, q) -> bool:
        """True when collision-free (the project's convention)."""
        coal, pin = self.coal, self.pin
        pin.framesForwardKinematics(self.m, self.d, q)
        for o, f, Ml in zip(self.objs, self.frame_of, self.local):
            M = self.d.oMf[f] * Ml
            o.setTransform(coal.Transform3s(M.rotation, M.translation))
            o.computeAABB()
        self.rob_mgr.update()
        cb = coal.CollisionCallBackDefault()
        self.rob_mgr.collide(self.env_mgr, cb)
        if cb.data.result.isCollision():
            return False
        for i, j in self.pairs:
            self.res.clear()
            if coal.collide(self.objs[i], self.objs[j], self.req, self.res):
                return False
        return True


def run(workdir) -> dict:
    import coal  # noqa: F401

    from problem import build_problem

    prob = build_problem()
    chk = CoalChecker(prob)
    Q = np.load(Path(workdir) / "coll_configs.npz")["q"]
    for q in Q[:20]:
        chk.check(q)
    t0 = time.perf_counter()
    verdict = [chk.check(q) for q in Q]
    dt = time.perf_counter() - t0
    from importlib.metadata import version

    return {"available": True, "version": version("coal"), "n_configs": len(Q), "us_per_config": 1e6 * dt / len(Q),
            "valid": verdict, "robot_shapes": len(chk.objs), "scene_objects": len(chk.env),
            "self_pairs": len(chk.pairs),
            "method": "coal: pinocchio FK, robot capsules/spheres vs scene primitives (exact) by two "
                      "DynamicAABBTreeCollisionManager, then the self pairs by coal.collide (Python loop)"}


if __name__ == "__main__":
    emit(guarded(run, sys.argv[1]))
