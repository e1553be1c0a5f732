"""Tests of humanoid_reach_ros.control.tasks and .limits on the real robot model."""
from __future__ import annotations

import time

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.control.hqp import HierarchicalQP, Level
from humanoid_reach_ros.control.limits import LimitRows, joint_limit_rows, velocity_damper_rows
from humanoid_reach_ros.control.tasks import (ComTask, DofSelection, FrameTask, PostureTask, compute_kinematics,
                                              integrate)
from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.robot.model import N_BASE_Q

DT = 0.005


def _random_q(robot, rng):
    j = robot.half_sitting_joints + rng.uniform(-0.3, 0.3, robot.n_joints)
    j = np.clip(j, robot.lower, robot.upper)
    base = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-0.5, 0.5, 3)), rng.uniform(-0.5, 0.5, 3))
    return robot.config(j, base)


def _non_gripper(robot):
    grip = set(robot.spec.gripper_joints)
    return [i for i, n in enumerate(robot.joint_names) if n not in grip]


@pytest.mark.parametrize("seed", range(3))
def test_task_jacobians_finite_difference(robot, seed):
    rng = np.random.default_rng(seed)
    m, d = robot.model, robot.data
    q = _random_q(robot, rng)
    target = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 0.5), np.array([0.4, -0.2, 0.9]))
    tasks = [FrameTask.of(robot, "r_hand_ee", target), FrameTask.of(robot, "l_sole", target.inverse()),
             ComTask(np.array([0.05, -0.02])), PostureTask(robot.half_sitting_joints, joints=(0, 5, 17))]
    dq = rng.normal(size=m.nv)
    h = 1e-6
    for task in tasks:
        compute_kinematics(m, d, q)
        r0 = task.rows(m, d, q)
        A, e0 = r0.A.copy(), r0.error.copy()
        q1 = integrate(m, q, h * dq)
        compute_kinematics(m, d, q1)
        e1 = task.rows(m, d, q1).error
        fd = (e1 - e0) / h
        assert np.allclose(fd, A @ dq, atol=1e-4 * max(1.0, np.abs(fd).max())), (type(task).__name__, fd, A @ dq)
        assert np.allclose(r0.b, -task.gain * e0)


def test_com_task_is_exact_pinocchio_com(robot):
    m, d = robot.model, robot.data
    q = _random_q(robot, np.random.default_rng(7))
    target = np.array([0.01, 0.02])
    r = ComTask(target, gain=0.5).rows(m, d, q)
    assert np.allclose(r.error, robot.com(q)[:2] - target, atol=1e-12)
    assert np.allclose(r.A, pin.jacobianCenterOfMass(m, d, q)[:2])
    assert r.A.shape == (2, m.nv)


def test_frame_task_mask_selects_rows(robot):
    m, d = robot.model, robot.data
    q = robot.half_sitting()
    compute_kinematics(m, d, q)
    full = FrameTask.of(robot, "r_hand_ee", pin.SE3.Identity()).rows(m, d, q)
    pos = FrameTask.of(robot, "r_hand_ee", pin.SE3.Identity(), mask=(1, 1, 1, 0, 0, 0)).rows(m, d, q)
    assert pos.A.shape == (3, m.nv) and np.allclose(pos.A, full.A[:3]) and np.allclose(pos.b, full.b[:3])


def test_dof_selection_drops_grippers(robot):
    dofs = DofSelection.without_grippers(robot)
    assert dofs.n == robot.model.nv - 2
    x = np.arange(dofs.n, dtype=float) + 1
    dq = dofs.expand(x)
    for name in robot.spec.gripper_joints:
        assert dq[6 + robot.joint_index[name]] == 0.0
    assert np.allclose(dofs.reduce(dq), x)


def test_joint_limit_rows_keep_joints_in_limits(robot):
    rng = np.random.default_rng(1)
    m = robot.model
    dofs = DofSelection.without_grippers(robot)
    sel = _non_gripper(robot)
    hqp = HierarchicalQP()
    for _ in range(20):
        # joints on, near or just outside their limits
        t = rng.choice([0.0, 1.0, 0.5, -1e-3, 1.001], size=robot.n_joints)
        j = robot.lower + t * (robot.upper - robot.lower)
        q = robot.config(j)
        lim = joint_limit_rows(q, robot.lower, robot.upper, DT, robot.velocity_limit, sel)
        push = rng.normal(size=dofs.n) * 5.0
        res = hqp.solve([Level(C=dofs.reduce(lim.G), d=lim.h), Level(A=np.eye(dofs.n), b=push)])
        dq = dofs.expand(res.x)
        q1 = integrate(m, q, dq)
        j1 = q1[N_BASE_Q:]
        inside = (j >= robot.lower) & (j <= robot.upper)
        tol = 1e-7
        ok = inside[sel]
        assert np.all(j1[sel][ok] >= robot.lower[sel][ok] - tol) and np.all(j1[sel][ok] <= robot.upper[sel][ok] + tol)
        # outside ones move back, never further out
        out = ~inside[sel]
        dist0 = np.maximum(robot.lower[sel] - j[sel], j[sel] - robot.upper[sel])
        dist1 = np.maximum(robot.lower[sel] - j1[sel], j1[sel] - robot.upper[sel])
        assert np.all(dist1[out] <= dist0[out] + tol)
        assert np.all(np.abs(dq[6:][sel]) <= robot.velocity_limit[sel] * DT + tol)


def _step_levels(robot, cm, q, dofs, tree, upper_tasks, d_i=0.10, d_s=0.005, xi=0.5):
    m, d = robot.model, robot.data
    compute_kinematics(m, d, q)
    lim = LimitRows.stack(joint_limit_rows(q, robot.lower, robot.upper, DT, robot.velocity_limit, _non_gripper(robot)),
                          velocity_damper_rows(m, d, cm, tree, d_i, d_s, xi))
    levels = [Level(C=dofs.reduce(lim.G), d=lim.h)]
    for group in upper_tasks:
        rows = [t.rows(m, d, q) for t in group]
        levels.append(Level(A=dofs.reduce(np.vstack([r.A for r in rows])), b=np.concatenate([r.b for r in rows])))
    return levels, len(lim)


def test_velocity_damper_stops_hand_at_sphere(robot, cm):
    m = robot.model
    # fixed base for this 2-level problem (the free base has no velocity limit; the
    # executor pins it with the feet at level 2)
    full = DofSelection.without_grippers(robot)
    dofs = DofSelection(full.nv, full.index[6:])
    q = robot.half_sitting()
    hand = robot.frame_pose(q, "r_hand_ee")
    centre = hand.translation + np.array([0.25, 0.0, 0.05])
    tree = SphereTree.build(centre[None], 0.08)
    # pull the hand (position only) into the sphere centre, fast
    task = FrameTask.of(robot, "r_hand_ee", pin.SE3(hand.rotation, centre), gain=0.2, mask=(1, 1, 1, 0, 0, 0))
    hqp = HierarchicalQP()
    d_s = 0.005
    dmin = np.inf
    for _ in range(300):
        levels, _ = _step_levels(robot, cm, q, dofs, tree, [[task]], d_s=d_s)
        res = hqp.solve(levels)
        q = integrate(m, q, dofs.expand(res.x))
        P0, P1, R = cm.world_shapes(q)
        dmin = min(dmin, float(tree.min_distance_batch(P0, P1, R).min()))
    assert dmin >= d_s - 1e-3, dmin
    assert dmin < 0.02  # the task really pushed the hand against the sphere


def test_lower_level_never_degrades_feet_and_com(robot, cm):
    m, d = robot.model, robot.data
    dofs = DofSelection.without_grippers(robot)
    q = robot.half_sitting()
    rs, ls = robot.stance_soles
    com_xy = robot.com(q)[:2]
    feet = [FrameTask.of(robot, "r_sole", rs, 0.5), FrameTask.of(robot, "l_sole", ls, 0.5), ComTask(com_xy, 0.5)]
    far = pin.SE3(np.eye(3), np.array([1.5, -0.8, 1.6]))  # unreachable
    hand = [FrameTask.of(robot, "r_hand_ee", far, 0.1)]
    posture = [PostureTask(robot.half_sitting_joints, 0.05, joints=tuple(_non_gripper(robot)))]
    hqp, top = HierarchicalQP(), HierarchicalQP()
    for _ in range(150):
        levels, _ = _step_levels(robot, cm, q, dofs, None, [feet, hand, posture])
        res = hqp.solve(levels)
        # the feet/COG rows are met as well as without the lower levels (unreachable hand)
        alone = top.solve(levels[:2])
        assert res.slacks[0] == pytest.approx(alone.slacks[0], abs=1e-6)
        assert res.slacks[1] == pytest.approx(alone.slacks[1], abs=1e-6)
        q = integrate(m, q, dofs.expand(res.x))
    compute_kinematics(m, d, q)
    # held to first order each step: what remains is the second-order integration drift
    assert np.linalg.norm(feet[0].error(d)) < 1e-4
    assert np.linalg.norm(feet[1].error(d)) < 1e-4
    assert np.linalg.norm(robot.com(q)[:2] - com_xy) < 1e-4
    assert robot.in_limits(q[N_BASE_Q:], tol=1e-6)
    # the hand did move toward the target
    assert np.linalg.norm(robot.frame_pose(q, "r_hand_ee").translation - far.translation) < \
        np.linalg.norm(robot.frame_pose(robot.half_sitting(), "r_hand_ee").translation - far.translation) - 0.1


def test_measure_four_level_solve_time(robot, cm):
    """Not a timed assertion: prints the per-step times of the executor's 4-level problem."""
    m = robot.model
    dofs = DofSelection.without_grippers(robot)
    q = robot.half_sitting()
    rs, ls = robot.stance_soles
    hand0 = robot.frame_pose(q, "r_hand_ee")
    target = pin.SE3(hand0.rotation, hand0.translation + np.array([0.25, -0.1, 0.15]))
    grid = np.mgrid[0.45:0.5:0.05, -0.6:0.6:0.05, 0.2:1.4:0.05].reshape(3, -1).T
    tree = SphereTree.build(grid, 0.03)
    feet = [FrameTask.of(robot, "r_sole", rs, 0.5), FrameTask.of(robot, "l_sole", ls, 0.5),
            ComTask(robot.com(q)[:2], 0.5)]
    groups = [feet, [FrameTask.of(robot, "r_hand_ee", target, 0.05)],
              [PostureTask(robot.half_sitting_joints, 0.05, joints=tuple(_non_gripper(robot)))]]
    hqp = HierarchicalQP()
    build, solve, rows, per_level = [], [], [], []
    for _ in range(300):
        t0 = time.perf_counter()
        levels, n_ineq = _step_levels(robot, cm, q, dofs, tree, groups)
        t1 = time.perf_counter()
        res = hqp.solve(levels)
        t2 = time.perf_counter()
        q = integrate(m, q, dofs.expand(res.x))
        build.append(t1 - t0), solve.append(t2 - t1), rows.append(n_ineq)
        per_level.append([lv.time_s for lv in res.levels])
    b, s = np.array(build[10:]) * 1e3, np.array(solve[10:]) * 1e3
    tot = b + s
    pl = np.array(per_level[10:]) * 1e3
    print(f"\n4-level step (n={dofs.n}, level-1 rows {min(rows)}..{max(rows)}): "
          f"total median {np.median(tot):.2f} ms p99 {np.percentile(tot, 99):.2f} ms; "
          f"rows+kinematics median {np.median(b):.2f} p99 {np.percentile(b, 99):.2f}; "
          f"HQP median {np.median(s):.2f} p99 {np.percentile(s, 99):.2f}; "
          f"per level median {np.round(np.median(pl, axis=0), 3)} p99 {np.round(np.percentile(pl, 99, axis=0), 3)}")
    assert res.ok


# ---------------------------------------------------------------- executor fast path (numba geometry, WORLD rows)
def test_world_point_rows_match_point_normal_rows(robot, cm):
    from humanoid_reach_ros.control.limits import point_normal_rows, support_masks, world_point_rows
    rng = np.random.default_rng(5)
    m, data = robot.model, robot.model.createData()
    q = _random_q(robot, rng)
    compute_kinematics(m, data, q)
    links = rng.integers(0, len(cm.frame_ids), size=12)
    fids = np.asarray(cm.frame_ids)[links]
    pts = rng.normal(size=(12, 3))
    nrm = rng.normal(size=(12, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    masks = support_masks(m, cm.frame_ids)[links]
    assert np.allclose(world_point_rows(data.J, masks, pts, nrm), point_normal_rows(m, data, fids, pts, nrm),
                       atol=1e-12)
    # indexed masks and the self-pair difference form give the same rows
    all_masks = support_masks(m, cm.frame_ids)
    assert np.allclose(world_point_rows(data.J, all_masks, pts, nrm, links), world_point_rows(data.J, masks, pts, nrm),
                       atol=1e-12)
    from humanoid_reach_ros.control.limits import pair_point_rows
    other = rng.integers(0, len(cm.frame_ids), size=12)
    pts_b = rng.normal(size=(12, 3))
    expect = (point_normal_rows(m, data, fids, pts, nrm)
              - point_normal_rows(m, data, np.asarray(cm.frame_ids)[other], pts_b, nrm))
    assert np.allclose(pair_point_rows(data.J, all_masks, links, pts, other, pts_b, nrm), expect, atol=1e-12)


def test_self_pair_geometry_matches_numpy(robot, cm):
    from humanoid_reach_ros.control.limits import self_pair_geometry
    from humanoid_reach_ros.robot.shapes import segment_segment_distance
    rng = np.random.default_rng(6)
    q = _random_q(robot, rng)
    P0, P1, R = cm.world_shapes(q)
    pi = np.ascontiguousarray(cm.pair_index[:, 0], dtype=np.int64)
    pj = np.ascontiguousarray(cm.pair_index[:, 1], dtype=np.int64)
    k, pa, pb, n, d, dmin = self_pair_geometry(np.ascontiguousarray(P0), np.ascontiguousarray(P1),
                                               np.ascontiguousarray(R), pi, pj, 10.0)
    ref, _, _ = segment_segment_distance(P0[pi], P1[pi], P0[pj], P1[pj])
    ref = ref - R[pi] - R[pj]
    assert len(k) == len(pi)
    assert np.allclose(d, ref, atol=1e-12) and dmin == pytest.approx(ref.min())
    assert np.allclose(np.linalg.norm(pb - pa, axis=1) - R[pi] - R[pj], d, atol=1e-12)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    k2, *_ = self_pair_geometry(np.ascontiguousarray(P0), np.ascontiguousarray(P1), np.ascontiguousarray(R),
                                pi, pj, 0.05)
    assert set(k2) == set(np.flatnonzero(ref <= 0.05))


def test_env_pair_geometry_matches_numpy():
    from humanoid_reach_ros.control.limits import env_pair_geometry
    from humanoid_reach_ros.robot.shapes import point_segment_distance
    rng = np.random.default_rng(7)
    P0, P1 = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    P1[2] = P0[2]                                   # a sphere shape
    s = rng.integers(0, 4, size=20).astype(np.int64)
    c = rng.normal(size=(20, 3))
    pts, nrm = env_pair_geometry(P0, P1, s, c)
    dist, u = point_segment_distance(c, P0[s], P1[s])
    assert np.allclose(pts, P0[s] + u[:, None] * (P1[s] - P0[s]), atol=1e-12)
    assert np.allclose(np.linalg.norm(c - pts, axis=1), dist, atol=1e-12)
    assert np.allclose(nrm * dist[:, None], c - pts, atol=1e-12)
