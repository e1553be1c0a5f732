"""The collision proof at the target (planning/enclosure.py, issue 35 item 2): a target in a
pocket the map closes all round is answered NO_GOAL_FOUND at once, and never a target some
collision-free posture reaches (a property test over random goal postures, each caged in a map
with a hole exactly where that posture's body passes)."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.codes import PlanError
from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.kinematics import Chain6
from humanoid_reach_ros.planning.enclosure import ArmTube, cell_size, trunk_cells
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.planning.suite import load_suite
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion
from humanoid_reach_ros.robot.model import RobotModel

H = 0.02      # the planner's resolution (config/reach_planner.yaml)


def _params() -> PlannerParams:
    """The node's parameters (config/reach_planner.yaml: a 1 cm safety margin on the map's spheres)."""
    with open(config_path("reach_planner.yaml")) as f:
        ros_p = yaml.safe_load(f)["/**"]["ros__parameters"]
    return PlannerParams(**{k: ros_p[k] for k in PlannerParams.__dataclass_fields__ if k in ros_p})


@pytest.fixture(scope="module", params=[("hrp2", True), ("talos", False), ("g1", False)],
                ids=["hrp2-reach-map", "talos", "g1"])
def planner(request):
    """The node's planner (its reach map off, as in the graph); HRP-2's with the map (the bench's)."""
    name, reach_map = request.param
    rp = ReachPlanner(RobotModel(name), params=replace(_params(), use_reach_map=reach_map))
    rp.warm_up()
    return rp


def _trunk_cells(rp: ReachPlanner) -> np.ndarray:
    """The trunk cells the proof searches: the reach map's inverse's, or the same grid without it."""
    return rp.reach.cells if rp.reach is not None else trunk_cells(rp.trunk_region, rp.params.reach_map_step_rad)[0]


def _case(name):
    return next(c for c in load_suite() if c.name == name)


def test_the_tubes_are_inside_the_arms_shapes():
    """Every robot's arms hold a tube; with the node's 1 cm safety margin each is thick enough for
    the 2 cm map (HRP-2's for 2 cm cells, the others' for 1 cm); without a margin the G1's is too
    thin (its proof is not tried)."""
    for name, cells in (("hrp2", (H, H)), ("talos", (H / 2, H / 2)), ("g1", (None, H / 2))):
        rp = ReachPlanner(RobotModel(name))
        tubes = [ArmTube.of(rp.robot, rp.collision_model, a) for a in ("right", "left")]
        assert all(t is not None and t.radius > 0 and 0 <= t.lead <= 0.1 for t in tubes), tubes
        assert (cell_size(tubes, H / 2, H), cell_size(tubes, H / 2 + 0.01, H)) == cells, (name, tubes)


def test_the_caged_valve_is_refused_at_once_and_the_low_valve_is_not(planner):
    caged = _case("caged_valve")
    planner.set_map(caged.voxels(H))
    for arm in ("right", "left", "auto"):
        t0 = time.perf_counter()
        out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(caged.region(), arm=arm, seed=0,
                                                                          time_budget_s=2.0))
        dt = time.perf_counter() - t0
        assert out.error == PlanError.NO_GOAL_FOUND and "proven" in out.message, out.message
        assert "closed pocket" in out.message and dt < 1.0, (dt, out.message)
        assert out.stats["samples"] == 0
    low = _case("low_valve")
    planner.set_map(low.voxels(H))
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(low.region(), arm="right", seed=0))
    assert out.success, out.message


def _goal_posture(rp: ReachPlanner, arm: str, rng: np.random.Generator):
    """A random balanced posture Algorithm 1 may sample: the arm's joints uniform in their limits,
    the trunk at a random cell centre of the reach map's inverse (legs by IK); None if it does not
    project."""
    limb = rp.robot.limbs[f"{arm}_arm"]
    chain = Chain6.from_model(rp.robot, limb.root, limb.joints, limb.tip)
    lo, hi = chain.lower, chain.upper
    cells = _trunk_cells(rp)
    cell = cells[rng.integers(len(cells))]
    q_plan = np.concatenate([rng.uniform(lo, hi), cell])[None]
    res = rp.projector.project_plan_config(q_plan, arm)
    return res.q[0] if bool(res.ok[0]) else None


def test_no_false_no_over_random_goal_postures(planner):
    """Property: whatever the map, if one collision-free posture (the trunk in a searched cell)
    puts the hand at the target, the proof does not refuse it. Each map is the adversary's: a
    closed box of voxels around that hand with every voxel the posture's shapes touch taken out
    (the hole the body passes through), plus random clutter taken out the same way."""
    rp = planner
    rng = np.random.default_rng(35)
    cm = rp.collision_model
    rho = H / 2 + rp.params.safety_margin_m
    tried = 0
    for k in range(400):
        arm = ("right", "left")[k % 2]
        q = _goal_posture(rp, arm, rng)
        if q is None:
            continue
        P0, P1, radii = cm.world_shapes(q)
        tip = np.array(rp.robot.frame_pose(q, rp.robot.limbs[f"{arm}_arm"].tip).translation)
        s = float(rng.uniform(0.1, 0.25))          # the box's half size around the hand
        g = np.arange(-s, s + 1e-9, H)
        X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
        shell = (np.abs(X) > s - H / 2) | (np.abs(Y) > s - H / 2) | (np.abs(Z) > s - H / 2)
        V = np.stack([X[shell], Y[shell], Z[shell]], 1) + tip
        V = np.vstack([V, tip + rng.uniform(-0.5, 0.5, (300, 3))])
        d = np.full(len(V), np.inf)
        for i in range(len(radii)):        # distance to every shape of the posture
            ab = P1[i] - P0[i]
            den = float(ab @ ab)
            t = np.zeros(len(V)) if den == 0 else np.clip((V - P0[i]) @ ab / den, 0, 1)
            d = np.minimum(d, np.linalg.norm(V - (P0[i] + t[:, None] * ab), axis=1) - radii[i])
        V = V[d > rho + 1e-4]              # the posture is collision-free in this map
        col = RobotCollision(rp.robot, cm, SphereTree.from_voxels(V, H, rp.params.safety_margin_m))
        region = WorkspaceGoalRegion(tip, np.eye(3), np.zeros(6), np.zeros(6))
        why = rp._enclosed(region, arm, col, None if rp.reach is None else rp.reach.cells)
        assert why == "", (rp.robot.name, arm, q.tolist(), s, why)
        tried += 1
        if tried >= 40:
            break
    assert tried >= 40


@pytest.mark.parametrize("name", ["hrp2", "talos", "g1"])
def test_the_tube_is_inside_the_shapes_at_random_arm_postures(name):
    """The tube's claim, checked where it is used: at random arm joints within the limits, every
    point of the polyline (tip, joint origins, into the chest) past the lead lies at least the
    tube's radius deep inside one of the robot's shapes."""
    import pinocchio as pin

    rp = ReachPlanner(RobotModel(name))
    model, cm = rp.robot.model, rp.collision_model
    data = model.createData()
    rng = np.random.default_rng(7)
    for arm in ("right", "left"):
        tube = ArmTube.of(rp.robot, cm, arm)
        limb = rp.robot.limbs[f"{arm}_arm"]
        jids = [model.getJointId(j) for j in limb.joints]
        for _ in range(30):
            q = pin.neutral(model)
            for j in jids:
                i = model.joints[j].idx_q
                q[i] = rng.uniform(model.lowerPositionLimit[i], model.upperPositionLimit[i])
            pin.framesForwardKinematics(model, data, q)
            root = data.oMf[model.getFrameId(limb.root)]
            pts = [data.oMf[model.getFrameId(limb.tip)].translation] + \
                [data.oMi[j].translation for j in reversed(jids)] + [root.act(tube.shoulder)]
            P0, P1, radii = cm.world_shapes(q)
            s0 = 0.0
            for a, b in zip(pts[:-1], pts[1:]):
                L = float(np.linalg.norm(b - a))
                for t in np.linspace(0.0, 1.0, max(2, int(L / 0.005) + 1)):
                    if s0 + t * L < tube.lead + 1e-9:
                        continue
                    p = a + t * (b - a)
                    ab = P1 - P0
                    den = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
                    u = np.clip(np.einsum("ij,ij->i", p - P0, ab) / den, 0.0, 1.0)
                    depth = np.max(radii - np.linalg.norm(p - (P0 + u[:, None] * ab), axis=1))
                    assert depth >= tube.radius - 1e-9, (name, arm, s0 + t * L, depth, tube.radius)
                s0 += L
