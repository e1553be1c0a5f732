"""Benchmark: goal sampling on the plant scene with the valve WGR (Kanehiro et al., Table I, Fig. 4).

* Map: the plant scene voxelized at 2 cm, without the valve group (exclude_groups=
  ("valve",)): the hand must touch the valve, so the valve itself cannot count as an
  obstacle (the pipes around it still do). Sphere tree with no extra safety margin.
* Region: eq. 3 around the valve centre (scene target, identity orientation).
* 100 goals with the analytic projector (Algorithm 1), seeded; Table I figures.
* The same sampling with a NUMERICAL projector (pinocchio damped least squares
  whole-body IK: hand 6D + both feet 6D + horizontal COG, from the Algorithm 1 seed),
  same sample stream, right arm then left arm, fewer goals (``NUM_GOALS``); time per
  goal and the ratio to the analytic one.
* ``doc/fig4_cog.png``: exact COG relative to COG_approx for the 100 goals, with the
  support polygon (the feet's bounding box, 23 x 34 cm) drawn around it.

Last stdout line: one JSON object.
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from humanoid_reach_ros.geometry.distance import RobotCollision  # noqa: E402
from humanoid_reach_ros.geometry.sphere_tree import SphereTree  # noqa: E402
from humanoid_reach_ros.planning.goal_sampler import TrunkSampling, cog_errors, sample_goals  # noqa: E402
from humanoid_reach_ros.planning.projector import Projector  # noqa: E402
from humanoid_reach_ros.planning.wgr import valve_region  # noqa: E402
from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

SEED = 20120514
N_GOALS = 100
NUM_GOALS = 10
RESOLUTION_M = 0.02
BATCH = 512
# numerical projector
NUM_MAX_IT = 60
NUM_DAMP = 1e-3
NUM_EPS = 1e-6


class NumericalProjector:
    """Whole-body damped least squares IK (the baseline the paper alludes to).

    Tasks stacked in one least-squares system (20 rows, nv = 36 unknowns): hand pose
    6D (log6 error in the local frame), right and left sole 6D at the stance poses,
    horizontal exact COG at ``COG_approx``. Start: the Algorithm 1 trunk pose from the
    sample's (z_t, rpy_t) with the reference joints. Step ``dq = J^T (J J^T + lambda
    I)^-1 e``, joints clipped to the limits, at most ``NUM_MAX_IT`` iterations; success
    when every error is below ``NUM_EPS``.
    """

    def __init__(self, robot: RobotModel, projector: Projector) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = self.model.createData()
        self.pr = projector
        self.fid = {n: robot.frame_id(n) for n in ("r_hand_ee", "l_hand_ee", "r_sole", "l_sole")}
        soles = robot.stance_soles
        self.feet = {"r_sole": soles[0], "l_sole": soles[1]}
        self.lo = self.model.lowerPositionLimit.copy()
        self.hi = self.model.upperPositionLimit.copy()
        self.lo[:7], self.hi[:7] = -np.inf, np.inf
        self.iterations = 0

    def solve(self, p_e, R_e, z_t, rpy_t, hand: str) -> tuple[bool, np.ndarray]:
        m, d = self.model, self.data
        p_t, R_t = self.pr.trunk_pose(np.array([z_t]), np.array([rpy_t]))
        q = self.pr._base(p_t, R_t, np.array([rpy_t]))[0]
        goals = {hand: pin.SE3(R_e, p_e), **self.feet}
        target_xy = self.pr.cog_approx_xy
        for _ in range(NUM_MAX_IT):
            self.iterations += 1
            pin.computeJointJacobians(m, d, q)
            pin.updateFramePlacements(m, d)
            com = pin.centerOfMass(m, d, q, False)
            Jc = pin.jacobianCenterOfMass(m, d, q, False)
            rows, errs = [], []
            for name, goal in goals.items():
                fid = self.fid[name]
                err = pin.log6(d.oMf[fid].actInv(goal)).vector
                J = pin.getFrameJacobian(m, d, fid, pin.ReferenceFrame.LOCAL)
                rows.append(pin.Jlog6(d.oMf[fid].actInv(goal)) @ J)
                errs.append(err)
            rows.append(Jc[:2])
            errs.append(target_xy - com[:2])
            e = np.concatenate(errs)
            if np.max(np.abs(e)) < NUM_EPS:
                jt = q[7:]
                return bool(np.all(jt >= self.lo[7:] - 1e-9) and np.all(jt <= self.hi[7:] + 1e-9)), q
            J = np.vstack(rows)
            dq = J.T @ np.linalg.solve(J @ J.T + NUM_DAMP * np.eye(len(e)), e)
            q = pin.integrate(m, q, dq)
            q[7:] = np.clip(q[7:], self.lo[7:], self.hi[7:])
        return False, q


def numerical_goals(region, n_goals, robot, collision, rng, trunk, projector) -> dict:
    num = NumericalProjector(robot, projector)
    t0 = time.perf_counter()
    goals = samples = checks = 0
    arms = {"right": 0, "left": 0}
    while goals < n_goals:
        p_e, R_e = region.sample(rng, BATCH)
        z_t, rpy_t = trunk.sample(rng, BATCH)
        for k in range(BATCH):
            samples += 1
            for hand, arm in (("r_hand_ee", "right"), ("l_hand_ee", "left")):  # noqa: B007 (read after the break)
                ok, q = num.solve(p_e[k], R_e[k], z_t[k], rpy_t[k], hand)
                if ok:
                    break
            if not ok:
                continue
            checks += 1
            if collision.check(q):
                goals += 1
                arms[arm] += 1
                if goals == n_goals:
                    break
    total = time.perf_counter() - t0
    return {"n_goals": goals, "time_per_goal_ms": 1e3 * total / goals, "total_time_s": total, "n_samples": samples,
            "collision_checks": checks, "arm_used": arms, "iterations": num.iterations,
            "time_per_iteration_us": 1e6 * total / max(num.iterations, 1)}


def support_polygon(robot: RobotModel, collision_model) -> tuple[np.ndarray, np.ndarray]:
    """xy bounding box (lo, hi) of the foot capsules at the stance (the support polygon)."""
    P0, P1, R = collision_model.world_shapes(robot.half_sitting())
    feet = [i for i, n in enumerate(collision_model.names) if "foot" in n]
    pts = np.concatenate([P0[feet, :2], P1[feet, :2]])
    r = R[feet].max()
    return pts.min(0) - r, pts.max(0) + r


def plot_fig4(err: np.ndarray, poly_lo: np.ndarray, poly_hi: np.ndarray, cog_xy: np.ndarray, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 6))
    lo, hi = (poly_lo - cog_xy) * 100, (poly_hi - cog_xy) * 100
    ax.plot([lo[1], hi[1], hi[1], lo[1], lo[1]], [lo[0], lo[0], hi[0], hi[0], lo[0]], "k-",
            label=f"support polygon {100 * (poly_hi - poly_lo)[0]:.0f} x {100 * (poly_hi - poly_lo)[1]:.0f} cm")
    ax.plot(err[:, 1] * 100, err[:, 0] * 100, "o", ms=4, color="tab:orange", label="exact COG")
    ax.plot(0, 0, "+", color="tab:blue", ms=12, mew=2, label="COG_approx")
    ax.set_xlabel("y [cm] (left)")
    ax.set_ylabel("x [cm] (forward)")
    ax.invert_xaxis()
    ax.set_aspect("equal")
    ax.grid(True, lw=0.3)
    ax.legend(loc="lower center", fontsize=8)
    ax.set_title(f"Exact COG relative to COG_approx, {len(err)} goals")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    robot = RobotModel()
    cm = load_collision_model(None, robot)
    scene = load_scene("scenes/plant.yaml")
    # The valve is left out of the map: the hand must touch it (WGR position = its centre).
    voxels = scene.voxelize(RESOLUTION_M, exclude_groups=("valve",))
    tree = SphereTree.from_voxels(voxels, RESOLUTION_M)
    collision = RobotCollision(robot, cm, tree)
    projector = Projector(robot)
    region = valve_region(scene.target.pose)
    trunk = TrunkSampling()

    sample_goals(region, 2, robot, collision, np.random.default_rng(0), trunk=trunk, projector=projector)  # JIT warm-up
    collision.reset_counters()
    goals = sample_goals(region, N_GOALS, robot, collision, np.random.default_rng(SEED), trunk=trunk,
                         batch_size=BATCH, projector=projector)
    st = goals.stats
    err = cog_errors(goals.q, robot, projector)
    lo, hi = support_polygon(robot, cm)
    plot_fig4(err, lo, hi, projector.cog_approx_xy, REPO / "doc" / "fig4_cog.png")

    # collision check cost on a larger batch of IK-valid configurations
    rng = np.random.default_rng(SEED + 1)
    p_e, R_e = region.sample(rng, 20000)
    z_t, rpy_t = trunk.sample(rng, 20000)
    res = projector.project_config(p_e, R_e, z_t, rpy_t)
    Qv = res.q[res.ok]
    collision.reset_counters()
    collision.check_batch(Qv)
    batch_check_us = 1e6 * collision.counters.check_time_per_config_s
    batch_fk_us = 1e6 * collision.counters.fk_time_per_config_s
    t0 = time.perf_counter()
    for q in Qv:
        collision.check(q)
    single_us = 1e6 * (time.perf_counter() - t0) / len(Qv)

    num = numerical_goals(region, NUM_GOALS, robot, collision, np.random.default_rng(SEED), trunk, projector)
    table = st.as_dict()
    print("Table I (analytic, Algorithm 1):")
    print(f"  average total goal sampling time  {table['time_per_goal_ms']:.2f} ms per goal")
    print(f"  collision detection               {table['collision_time_share_pct']:.2f} % of total time, "
          f"called {st.collision_checks} times ({table['collision_time_per_call_ms']:.4f} ms/call)")
    print(f"  the number of samples             {st.n_samples}")
    print(f"  used arm (right/left)             {st.arm_used['right']}/{st.arm_used['left']}")
    f = st.ik_failures
    print(f"  IK failure  arm: {f['right_arm']}(right)/{f['left_arm']}(left)  "
          f"leg: {f['right_leg']}(right)/{f['left_leg']}(left)")
    print(f"numerical projector: {num['time_per_goal_ms']:.1f} ms per goal over {num['n_goals']} goals; "
          f"analytic is {num['time_per_goal_ms'] / table['time_per_goal_ms']:.0f}x faster")
    print(f"COG exact - approx [cm]: mean {100 * err.mean(0)}, max |.| {100 * np.abs(err).max(0)}")
    out = {
        "bench": "goal_sampling",
        "scene": "plant", "voxels": int(len(voxels)), "resolution_m": RESOLUTION_M,
        "map": "valve group excluded (the hand touches it)",
        "region": "eq. 3 around the valve centre, identity orientation",
        "trunk_sampling": {k: list(getattr(trunk, k)) for k in ("z_t", "roll", "pitch", "yaw")},
        "seed": SEED, "batch_size": BATCH,
        "analytic": table,
        "collision_check_us": {"batch_per_config": batch_check_us, "batch_fk_per_config": batch_fk_us,
                               "single_call_incl_fk": single_us, "n_configs": int(len(Qv))},
        "numerical": num | {"method": f"pinocchio DLS whole-body IK (hand 6D + feet 6D + COG xy), "
                                      f"lambda={NUM_DAMP}, max {NUM_MAX_IT} it, eps {NUM_EPS}"},
        "analytic_speedup_vs_numerical": num["time_per_goal_ms"] / table["time_per_goal_ms"],
        "cog_exact_minus_approx_m": {
            "mean_xy": err.mean(0).tolist(), "max_abs_xy": np.abs(err).max(0).tolist(),
            "mean_norm": float(np.linalg.norm(err, axis=1).mean()),
            "max_norm": float(np.linalg.norm(err, axis=1).max()),
        },
        "support_polygon_m": {"lo": lo.tolist(), "hi": hi.tolist()},
        "targets": {"time_per_goal_ms<=100": table["time_per_goal_ms"] <= 100.0,
                    "collision_check_us<=16": batch_check_us <= 16.0,
                    "analytic>=10x_numerical": num["time_per_goal_ms"] / table["time_per_goal_ms"] >= 10.0},
        "figure": "doc/fig4_cog.png",
        "machine": {"processor": platform.processor(), "machine": platform.machine(), "node": platform.node(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "pinocchio": pin.__version__},
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
