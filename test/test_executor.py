"""Tests of humanoid_reach_ros.control.executor (whole-body 5 ms executor, Kanehiro Sec. IV).

No timing assertions (speed figures come from bench/execution.py)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.control.executor import ExecutorParams, StepResult, WholeBodyExecutor
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory
from humanoid_reach_ros.planning.wgr import valve_region
from humanoid_reach_ros.robot.model import N_BASE_Q
from humanoid_reach_ros.sim.scene import load_scene

DT = 0.005


@pytest.fixture(scope="module")
def plant():
    """Plant scene (2 cm voxels, valve excluded), its sphere tree and the planned right-arm reach."""
    scene = load_scene("scenes/plant.yaml")
    voxels = scene.voxelize(0.02, exclude_groups=("valve",))
    planner = ReachPlanner(params=PlannerParams(time_budget_s=5.0))
    planner.set_map(voxels)
    out = planner.plan(planner.robot.half_sitting_joints, PlanRequest(valve_region(scene.target.pose), arm="right",
                                                                       seed=3))
    assert out.success, out.message
    return SphereTree.from_voxels(voxels, 0.02), out.trajectory


def _arm_reference(robot, delta: dict[str, float], duration: float = 1.0) -> SplineTrajectory:
    j0 = robot.half_sitting_joints
    j1 = j0.copy()
    for name, d in delta.items():
        j1[robot.joint_index[name]] += d
    return SplineTrajectory(np.vstack([j0, j1]), np.array([0.0, duration]))


def _run(ex: WholeBodyExecutor, steps: int) -> list[StepResult]:
    return [ex.step() for _ in range(steps)]


def _sole_poses(robot, q):
    return [robot.frame_pose(q, f) for f in ("r_sole", "l_sole")]


# ---------------------------------------------------------------- priorities
def test_priority_ordering_unreachable_hand(robot, cm):
    """Hand (level 3) asked far beyond reach: feet and COG (level 2) do not yield, the hand
    gets as close as it can, joint limits (level 1) hold."""
    ex = WholeBodyExecutor(robot, cm, ExecutorParams())
    q0 = robot.half_sitting()
    ex.start(q0, SplineTrajectory(robot.half_sitting_joints[None], np.zeros(1)), "right")
    far = ex.reference_hand(robot.half_sitting_joints)
    target = pin.SE3(far.rotation, far.translation + np.array([1.5, -0.5, 0.3]))
    ex.reference_hand = lambda joints: target          # conflicting level-3 task
    soles0 = _sole_poses(robot, q0)
    com0 = robot.com(q0)[:2]
    d0 = np.linalg.norm(robot.frame_pose(q0, "r_hand_ee").translation - target.translation)
    for r in _run(ex, 200):
        j = r.joints
        assert np.all(j >= robot.lower) and np.all(j <= robot.upper)
    q = ex.q
    for s0, s in zip(soles0, _sole_poses(robot, q)):
        assert np.linalg.norm(s.translation - s0.translation) < 1e-4
        assert np.linalg.norm(pin.log3(s0.rotation.T @ s.rotation)) < 1e-4
    assert np.linalg.norm(robot.com(q)[:2] - com0) < 1e-4
    d = np.linalg.norm(robot.frame_pose(q, "r_hand_ee").translation - target.translation)
    assert d < d0 - 0.1                          # it did reach toward the target
    assert r.metrics.level_slack[1] < 1e-3       # level 2 held (to the fallback tolerance when saturated)
    assert r.metrics.level_slack[2] > 0.1        # level 3 infeasible, least squares


def test_feet_and_cog_do_not_drift_toward_an_unreachable_target(robot, cm):
    """1.5 s (300 steps) toward a hand target 1.6 m out of reach: the feet and the exact COG
    (level 2) end within 1e-6 of where they started; their error never accumulates while
    level 3 is infeasible, and the joints stay within their limits. (Was 2,000 steps, 61 s of
    the suite's 9 min, then 600: the arm is stretched against its limits within the first
    second, every later step is the same infeasible solve.)"""
    ex = WholeBodyExecutor(robot, cm, ExecutorParams())
    q0 = robot.half_sitting()
    ex.start(q0, SplineTrajectory(robot.half_sitting_joints[None], np.zeros(1)), "right")
    far = ex.reference_hand(robot.half_sitting_joints)
    target = pin.SE3(far.rotation, far.translation + np.array([1.5, -0.5, 0.3]))
    ex.reference_hand = lambda joints: target
    soles0, com0 = _sole_poses(robot, q0), robot.com(q0)[:2]
    for r in _run(ex, 300):
        assert np.all(r.joints >= robot.lower) and np.all(r.joints <= robot.upper)
    q = ex.q
    for s0, s in zip(soles0, _sole_poses(robot, q)):
        assert np.linalg.norm(s.translation - s0.translation) <= 1e-6
        assert np.linalg.norm(pin.log3(s0.rotation.T @ s.rotation)) <= 1e-6
    assert np.linalg.norm(robot.com(q)[:2] - com0) <= 1e-6
    assert r.metrics.level_slack[1] <= 1e-9 and r.metrics.level_slack[2] > 0.1


def test_priority_ordering_collision_beats_hand(robot, cm):
    """A sphere on the straight hand path: level 1 (damper) stops the hand at d_s; level 3 yields."""
    ex = WholeBodyExecutor(robot, cm, ExecutorParams(security_distance_m=0.01))
    q0 = robot.half_sitting()
    hand0 = robot.frame_pose(q0, "r_hand_ee")
    target = pin.SE3(hand0.rotation, hand0.translation + np.array([0.3, 0.0, 0.0]))
    # a wall of spheres across the straight path, 15 cm in front of the hand
    yz = np.mgrid[-0.25:0.25:0.03, -0.25:0.25:0.03].reshape(2, -1).T
    wall = np.column_stack([np.full(len(yz), 0.15), yz]) + hand0.translation
    ex.set_environment(SphereTree.build(wall, 0.02))
    ex.start(q0, SplineTrajectory(robot.half_sitting_joints[None], np.zeros(1)), "right")
    ex.reference_hand = lambda joints: target
    dmin = min(r.metrics.min_distance_m for r in _run(ex, 300))
    assert dmin >= 0.005        # held near d_s (first-order dampers: a few mm of linearisation error)
    assert ex.step().metrics.hand_error_m > 0.05    # the hand did not get through


# ---------------------------------------------------------------- limits
def test_joint_limits_never_exceeded_when_pushed(robot, cm):
    """The reference drives several joints beyond their limits: the level-1 rows keep every
    commanded joint inside [lower, upper] at every step (nothing is clipped afterwards)."""
    names = ("RARM_JOINT0", "RARM_JOINT3", "CHEST_JOINT1", "LARM_JOINT1")
    hs = robot.half_sitting_joints
    j1 = hs.copy()
    for n in names:
        i = robot.joint_index[n]
        j1[i] = robot.upper[i] + 0.5 if n != "RARM_JOINT3" else robot.lower[i] - 0.5
    ref = SplineTrajectory(np.vstack([hs, j1]), np.array([0.0, 1.0]))
    ex = WholeBodyExecutor(robot, cm, ExecutorParams())
    ex.start(robot.half_sitting(), ref, "right")
    at_limit = set()
    for r in _run(ex, 300):
        assert np.all(r.joints >= robot.lower) and np.all(r.joints <= robot.upper)
        for n in names:
            i = robot.joint_index[n]
            if min(r.joints[i] - robot.lower[i], robot.upper[i] - r.joints[i]) < 1e-6:
                at_limit.add(n)
    assert len(at_limit) >= 3                   # the run really pushed against the limits


def test_velocity_limits_and_no_jump_on_start_from_elsewhere(robot, cm):
    """start() from a configuration far from the reference's first point: the command
    moves at most velocity_limit * dt per step (blend + level-1 rows), from q itself."""
    params = ExecutorParams(velocity_scale=0.5)
    ex = WholeBodyExecutor(robot, cm, params)
    hs = robot.half_sitting_joints
    j_other = hs.copy()
    for n, d in (("RARM_JOINT0", -0.8), ("RARM_JOINT3", -0.6), ("LARM_JOINT0", -0.4)):
        j_other[robot.joint_index[n]] += d
    q_other = robot.config(j_other, robot.base_on_feet(j_other))
    ref = _arm_reference(robot, {"RARM_JOINT1": -0.3})
    ex.start(q_other, ref, "right")
    vmax = robot.velocity_limit * params.velocity_scale * DT + 1e-12
    prev = q_other[N_BASE_Q:]
    for r in _run(ex, 300):
        assert np.all(np.abs(r.joints - prev) <= vmax)
        prev = r.joints
    # it converged onto the reference's hand pose
    assert r.metrics.hand_error_m < 1e-3 and r.done


def test_hold_is_smooth_and_stops(robot, cm):
    params = ExecutorParams()
    ex = WholeBodyExecutor(robot, cm, params)
    ref = _arm_reference(robot, {"RARM_JOINT0": -1.0, "RARM_JOINT3": -0.5}, duration=1.0)
    ex.start(robot.half_sitting(), ref, "right")
    prev = robot.half_sitting_joints
    vmax = robot.velocity_limit * DT + 1e-12
    for r in _run(ex, 100):                     # mid-motion
        prev = r.joints
    ex.hold()
    assert ex.holding and ex.active
    steps = _run(ex, 200)
    for r in steps:
        assert np.all(np.abs(r.joints - prev) <= vmax)
        assert r.done
        prev = r.joints
    assert np.max(np.abs(steps[-1].joints - steps[-2].joints)) < 1e-6     # at rest
    # hold(q) on a running executor keeps the commanded configuration (no jump)
    q_far = robot.half_sitting()
    ex.hold(q_far)
    r = ex.step()
    assert np.all(np.abs(r.joints - prev) <= vmax)


def test_hold_before_start_needs_q(robot, cm):
    ex = WholeBodyExecutor(robot, cm)
    with pytest.raises(ValueError, match="hold"):
        ex.hold()
    ex.hold(robot.half_sitting())
    r = ex.step()
    assert np.allclose(r.joints, robot.half_sitting_joints, atol=1e-9)


# ---------------------------------------------------------------- plant reach
def test_plant_right_reach_feet_cog_distance(robot, cm, plant):
    tree, ref = plant
    ex = WholeBodyExecutor(robot, cm, ExecutorParams())
    ex.set_environment(tree)
    j0 = ref.position(0.0)
    q0 = robot.config(j0, robot.base_on_feet(j0))
    soles0 = _sole_poses(robot, q0)
    ex.start(q0, ref, "right")
    n = int(np.ceil(ref.duration / DT)) + 60
    results = _run(ex, n)
    m = [r.metrics for r in results]
    assert min(x.min_distance_m for x in m) >= 0.0
    assert min(x.min_distance_m for x in m) >= ExecutorParams().security_distance_m - 2e-3
    assert max(x.com_error_m for x in m) < 1e-3
    assert min(x.self_distance_m for x in m) >= 0.0
    assert max(x.spheres_in_bound for x in m) > 0              # the map matters on this reach
    for r in results[:: 25] + [results[-1]]:
        for s0, s in zip(soles0, _sole_poses(robot, r.q)):
            assert np.linalg.norm(s.translation - s0.translation) < 1e-4
    assert results[-1].done
    assert m[-1].hand_error_m < 1e-3 and m[-1].progress == 1.0
    assert all(len(x.level_slack) == 4 for x in m)


def test_late_steps_follow_the_clock_within_the_limits(robot, cm, plant):
    """Every 10th step comes 3 periods late (step(t) with the deadline's time): the motion ends
    at the same reference time as a regular run (not stretched), never exceeds the joint
    velocity limits over the elapsed time, and feet, COG, joint limits and distance hold."""
    tree, ref = plant
    j0 = ref.position(0.0)
    q0 = robot.config(j0, robot.base_on_feet(j0))
    soles0 = _sole_poses(robot, q0)
    runs = {}
    for late in (False, True):
        ex = WholeBodyExecutor(robot, cm, ExecutorParams())
        ex.set_environment(tree)
        ex.start(q0, ref, "right")
        t, out = 0.0, []
        while not (out and out[-1][1].done) and len(out) < 2000:
            dt = 4 * DT if late and len(out) % 10 == 9 else DT
            t += dt
            out.append((dt, ex.step(t)))
        runs[late] = out
    regular, late = runs[False], runs[True]
    assert late[-1][1].done and regular[-1][1].done
    # not stretched: done at the same reference time (within the settling of a step or two)
    assert abs(late[-1][1].metrics.t - regular[-1][1].metrics.t) <= 3 * DT
    assert len(late) < len(regular)
    v = robot.velocity_limit
    prev = j0
    for dt, r in late:
        assert np.all(np.abs(r.joints - prev) <= v * dt * (1 + 1e-9) + 1e-12)   # within v over the elapsed time
        assert np.all(r.joints >= robot.lower) and np.all(r.joints <= robot.upper)
        prev = r.joints
    m = [r.metrics for _, r in late]
    assert min(x.min_distance_m for x in m) >= ExecutorParams().security_distance_m - 2e-3
    assert max(x.com_error_m for x in m) < 1e-3
    for _, r in late[::25] + [late[-1]]:
        for s0, s in zip(soles0, _sole_poses(robot, r.q)):
            assert np.linalg.norm(s.translation - s0.translation) < 1e-4
    assert m[-1].hand_error_m < 1e-3


def test_without_com_compensation_the_cog_moves(robot, cm):
    ref = _arm_reference(robot, {"RARM_JOINT0": -1.2, "LARM_JOINT0": -1.2}, duration=1.0)
    drift = {}
    for on in (True, False):
        ex = WholeBodyExecutor(robot, cm, ExecutorParams(com_compensation=on))
        ex.start(robot.half_sitting(), ref, "right")
        drift[on] = max(r.metrics.com_error_m for r in _run(ex, 260))
    assert drift[True] < 1e-4
    assert drift[False] > 5e-3



def test_com_motion_after_cancelled_uncompensated_motion(robot, cm, plant):
    """Issue #4: forward reach (COG on) -> backward WITHOUT compensation cancelled at 27 %
    (the COG drifts ~5 cm) -> backward WITH compensation from there. The COG target
    ramps back to its nominal point instead of being held off-centre for the whole
    motion: no OSQP fallback, level 1 exact, distances >= d_s, the hand and the COG track,
    the posture reaches the reference and the COG ends at its nominal point."""
    tree, fwd = plant
    bwd = SplineTrajectory(fwd.waypoints[::-1].copy(), fwd.times[-1] - fwd.times[::-1])
    ex = WholeBodyExecutor(robot, cm, ExecutorParams())
    ex.set_environment(tree)
    j0 = fwd.position(0.0)
    q0 = robot.config(j0, robot.base_on_feet(j0))
    com_nominal = robot.com(q0)[:2]
    ex.start(q0, fwd, "right")
    for _ in range(int(np.ceil(fwd.duration / DT)) + 60):
        if ex.step().done:
            break
    ex.start(ex.q, bwd, "right", params=ex.with_params(com_compensation=False))
    while ex.step().metrics.progress < 0.27:
        pass
    ex.hold()
    ex.step()
    q1 = ex.q
    assert np.linalg.norm(robot.com(q1)[:2] - com_nominal) > 0.03      # the cancelled motion moved the COG
    soles1 = _sole_poses(robot, q1)
    ex.start(q1, bwd, "right", params=ex.with_params(com_compensation=True))
    results = _run(ex, int(np.ceil(bwd.duration / DT)) + 60)
    m = [r.metrics for r in results]
    d_s = ExecutorParams().security_distance_m
    assert not any(x.fallback for x in m)
    assert max(x.level_slack[0] for x in m) < 1e-6
    assert min(x.min_distance_m for x in m) >= d_s - 2e-3
    assert max(x.com_error_m for x in m) < 2e-3
    assert max(x.hand_error_m for x in m) < 1e-2
    assert results[-1].done and m[-1].hand_error_m < 1e-3
    assert np.linalg.norm(robot.com(ex.q)[:2] - com_nominal) < 2e-3
    assert np.max(np.abs(results[-1].joints - bwd.position(bwd.duration))) < 0.05
    for s0, s in zip(soles1, _sole_poses(robot, ex.q)):
        assert np.linalg.norm(s.translation - s0.translation) < 1e-4


def test_start_inside_security_distance_stays_feasible(robot, cm):
    """A start with the hand already inside d_s: the dampers allow the distance to grow
    and never to shrink (h >= 0), so level 1 stays feasible and exact at every step."""
    d_s = 0.03
    ex = WholeBodyExecutor(robot, cm, ExecutorParams(security_distance_m=d_s))
    q0 = robot.half_sitting()
    P0, P1 = ex._fk.world_shapes(q0)
    hand = robot.frame_pose(q0, "r_hand_ee").translation
    k = int(np.argmin(np.minimum(np.linalg.norm(P0 - hand, axis=1), np.linalg.norm(P1 - hand, axis=1))))
    # a sphere 1 cm from the hand shape's surface, in front of it
    centre = P0[k] + np.array([cm.radii[k] + 0.01 + 0.02, 0.0, 0.0])
    ex.set_environment(SphereTree.build(centre[None], 0.02))
    target = robot.frame_pose(q0, "r_hand_ee")
    target = pin.SE3(target.rotation, target.translation + np.array([0.05, 0.0, 0.0]))
    ex.start(q0, SplineTrajectory(robot.half_sitting_joints[None], np.zeros(1)), "right")
    ex.reference_hand = lambda joints: target          # pushes the hand into the sphere
    prev = None
    for r in _run(ex, 100):
        m = r.metrics
        assert m.level_slack[0] < 1e-6
        if prev is not None and prev < d_s:
            assert m.min_distance_m >= prev - 1e-3         # inside d_s: never closer (first order)
        prev = m.min_distance_m
        assert np.all(r.joints >= robot.lower) and np.all(r.joints <= robot.upper)
    assert prev > 0.0

def test_done_and_metrics_fields(robot, cm):
    ex = WholeBodyExecutor(robot, cm)
    ref = _arm_reference(robot, {"RARM_JOINT0": -0.2}, duration=0.2)
    ex.start(robot.half_sitting(), ref, "right")
    assert ex.duration == pytest.approx(0.2)
    results = _run(ex, 100)
    assert results[0].metrics.t == pytest.approx(DT)
    assert results[-1].done and not results[0].done
    assert results[-1].metrics.min_distance_m == np.inf        # no map
    assert results[-1].metrics.active_levels == 4
    assert results[-1].q.shape == (robot.model.nq,) and results[-1].joints.shape == (robot.n_joints,)


# ---------------------------------------------------------------- bad input
def test_bad_inputs_raise_clear_errors(robot, cm):
    ex = WholeBodyExecutor(robot, cm)
    ref = _arm_reference(robot, {"RARM_JOINT0": -0.2})
    q = robot.half_sitting()
    with pytest.raises(ValueError, match="not active"):
        ex.step()
    bad = q.copy()
    bad[10] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ex.start(bad, ref, "right")
    with pytest.raises(ValueError, match="37"):
        ex.start(q[:-1], ref, "right")
    with pytest.raises(ValueError, match="unknown arm"):
        ex.start(q, ref, "middle")
    with pytest.raises(ValueError, match="joints"):
        ex.start(q, SplineTrajectory(np.zeros((2, 5)), np.array([0.0, 1.0])), "right")
    bad_ref = SplineTrajectory(np.vstack([robot.half_sitting_joints] * 2), np.array([0.0, 1.0]))
    bad_ref.waypoints[1, 3] = np.inf
    with pytest.raises(ValueError, match="NaN or inf"):
        ex.start(q, bad_ref, "right")
    with pytest.raises(ValueError, match="quaternion"):
        q2 = q.copy()
        q2[3:7] = [0.0, 0.0, 0.0, 2.0]
        ex.start(q2, ref, "right")
    with pytest.raises(ValueError, match="SphereTree"):
        ex.set_environment("map")
    with pytest.raises(ValueError, match="damper_xi"):
        ExecutorParams(damper_xi=2.0).validate()
    with pytest.raises(ValueError, match="solver"):
        WholeBodyExecutor(robot, cm, ExecutorParams(solver="magic"))
    with pytest.raises(ValueError, match="NaN"):
        ex.hold(bad)
    # still usable after the errors
    ex.start(q, ref, "right")
    assert ex.step().metrics.t == pytest.approx(DT)


def test_osqp_solver_gives_the_same_motion(robot, cm):
    """The closed-form solver and the OSQP cascade agree when no inequality is active."""
    ref = _arm_reference(robot, {"RARM_JOINT0": -0.4, "RARM_JOINT3": -0.3}, duration=1.0)
    out = {}
    for solver in ("nullspace", "osqp"):
        ex = WholeBodyExecutor(robot, cm, ExecutorParams(solver=solver))
        ex.start(robot.half_sitting(), ref, "right")
        out[solver] = np.array([r.joints for r in _run(ex, 60)])
    assert np.allclose(out["nullspace"], out["osqp"], atol=1e-4)


def test_warm_up_leaves_no_state(robot, cm):
    ex = WholeBodyExecutor(robot, cm)
    ex.warm_up()
    assert not ex.active
    with pytest.raises(ValueError, match="not active"):
        ex.step()


FIRST_STEP_SCRIPT = r'''
import pickle, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from humanoid_reach_ros.control.executor import ExecutorParams, WholeBodyExecutor
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.geometry.trajectory import SplineTrajectory, TrajectoryOptions
from humanoid_reach_ros.nodes.common import scene_file_voxels
from humanoid_reach_ros.execution.process import _warm_up_cluttered
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model

def signatures():
    out = set()
    for name, mod in list(sys.modules.items()):
        if name.startswith("humanoid_reach_ros"):
            for attr, f in vars(mod).items():
                if isinstance(f, CPUDispatcher):
                    out |= {(name, attr, str(s)) for s in f.signatures}
    return out

robot = RobotModel()
cm = load_collision_model(None, robot)
ex = WholeBodyExecutor(robot, cm, ExecutorParams())
ex.warm_up()                                                   # what the loop process does before its loop
_warm_up_cluttered(WholeBodyExecutor(robot, cm, ExecutorParams()), robot)
warm = signatures()
far = SphereTree.from_voxels(scene_file_voxels(str(config_path("scenes/two_valves.yaml")), 0.02, ()), 0.02)
hand = robot.frame_pose(robot.half_sitting(), robot.hand_frames["right"]).translation
near = SphereTree.from_voxels(hand + np.array([[0.06, 0.0, 0.0], [0.06, 0.02, 0.0]]), 0.02)
j = robot.half_sitting_joints.copy()
g = j.copy()
g[[robot.joint_index[n] for n in robot.spec.head_joints]] = [0.0, 0.6]
spl = SplineTrajectory.from_path(np.stack([j, g]), TrajectoryOptions(joint_velocity=np.full(len(j), 1.0),
                                                                    min_segment_duration_s=0.1))
ex.start(robot.half_sitting(), spl, "right")
for k, tree in enumerate((None, far, near, far)):              # the maps as the pipe delivers them
    ex.set_environment(pickle.loads(pickle.dumps(tree)))
    for i in range(5):
        ex.step((5 * k + i + 1) * 0.005)
new = sorted(signatures() - warm)
print("NEW", new)
'''


def test_no_kernel_is_compiled_or_loaded_in_a_control_step(tmp_path):
    """After the loop process's warm-up, no step compiles or loads a numba kernel, whatever map
    the pipe delivers (far from the robot, near it, none). A tree received through the pipe
    once had writable arrays (pickle's default) where the warm-up's were read-only: its first
    query loaded another specialisation from numba's cache inside a step (15-22 ms, the
    overruns of a fresh graph's first motion in bench/session). A fresh interpreter: another
    test in this process may have compiled anything already."""
    import subprocess
    import sys
    script = tmp_path / "first_step.py"
    script.write_text(FIRST_STEP_SCRIPT)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "NEW []", out.stdout[-3000:]


def test_a_tree_through_a_pipe_stays_read_only():
    import pickle
    tree = pickle.loads(pickle.dumps(SphereTree.from_voxels(np.zeros((3, 3)) + [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                                                            0.02)))
    for a in (tree.centers, tree.radii, tree.nodes, tree.children, tree.rule):
        assert not a.flags.writeable
