"""Closed-form limb IK (humanoid_reach_ros.kinematics.hand_derived) against pinocchio."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.kinematics.hand_derived import IKReason, LimbIK, LimbStructureError
from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel

LIMBS = ("right_leg", "left_leg", "right_arm", "left_arm")
N_RANDOM = 10_000
POS_TOL = 1e-9   # m
ROT_TOL = 1e-9   # rad


@pytest.fixture(scope="module")
def iks(robot) -> LimbIKSet:
    return LimbIKSet(robot)


def rot_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle of Ra^T Rb, atan2 form (accurate near 0, unlike arccos of the trace)."""
    D = np.einsum("nji,njk->nik", Ra, Rb)
    skew = np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=1), 0.5 * (np.trace(D, axis1=1, axis2=2) - 1.0))


def random_rotations(rng, n: int) -> np.ndarray:
    qv = rng.normal(size=(n, 4))
    qv /= np.linalg.norm(qv, axis=1, keepdims=True)
    x, y, z, w = qv.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


_CACHE: dict[str, dict[str, np.ndarray]] = {}


def sampled_poses(robot: RobotModel, limb: str) -> dict[str, np.ndarray]:
    """N_RANDOM whole-body configurations: random base pose, every joint uniform in its
    limits; root and tip poses of ``limb`` from pinocchio. Random numbers are drawn in
    bulk, pinocchio's FK runs once per configuration."""
    if limb not in _CACHE:
        rng = np.random.default_rng(20240611 + LIMBS.index(limb))
        spec = robot.limbs[limb]
        m, d = robot.model, robot.model.createData()
        fr, ft = robot.frame_id(spec.root), robot.frame_id(spec.tip)
        joints = rng.uniform(robot.lower, robot.upper, (N_RANDOM, robot.n_joints))
        base_p = rng.uniform(-2.0, 2.0, (N_RANDOM, 3))
        base_R = random_rotations(rng, N_RANDOM)
        Q = np.empty((N_RANDOM, m.nq))
        Q[:, :3] = base_p
        for i in range(N_RANDOM):
            Q[i, 3:7] = pin.Quaternion(base_R[i]).coeffs()
        Q[:, 7:] = joints
        out = {k: np.empty((N_RANDOM, 3)) for k in ("root_p", "tip_p")}
        out.update({k: np.empty((N_RANDOM, 3, 3)) for k in ("root_R", "tip_R")})
        for i in range(N_RANDOM):
            pin.framesForwardKinematics(m, d, Q[i])
            out["root_p"][i], out["root_R"][i] = d.oMf[fr].translation, d.oMf[fr].rotation
            out["tip_p"][i], out["tip_R"][i] = d.oMf[ft].translation, d.oMf[ft].rotation
        out["q"] = joints[:, list(spec.joint_index)]
        out["Q"] = Q
        _CACHE[limb] = out
    return _CACHE[limb]


# ------------------------------------------------------------------ structure
def test_structure_read_from_model(iks):
    assert set(iks.names) == set(LIMBS)
    for limb in LIMBS:
        ik = iks[limb]
        assert ik.kind == ("leg" if "leg" in limb else "arm")
        assert ik.l1 == pytest.approx(0.30 if ik.kind == "leg" else 0.25)
        assert ik.l2 == pytest.approx(0.30 if ik.kind == "leg" else 0.25)
        assert np.allclose(ik.te, [0, 0, -0.105 if ik.kind == "leg" else -0.17])
        assert np.all(ik.lower < ik.upper)


@pytest.mark.parametrize("bad", ["lateral", "axis_offset", "rotated"])
def test_structure_violation_raises(bad):
    robot = RobotModel()  # private copy: mutated below
    m = robot.model
    names = robot.limbs["right_leg"].joints
    if bad == "lateral":      # knee carries a lateral offset
        j = m.getJointId(names[3])
        m.jointPlacements[j] = pin.SE3(np.eye(3), np.array([0.0, 0.01, -0.30]))
    elif bad == "axis_offset":  # hip roll no longer intersects hip yaw
        j = m.getJointId(names[1])
        m.jointPlacements[j] = pin.SE3(np.eye(3), np.array([0.02, 0.0, 0.0]))
    else:                     # ankle pitch link frame rotated
        j = m.getJointId(names[4])
        m.jointPlacements[j] = pin.SE3(pin.rpy.rpyToMatrix(0.1, 0, 0), np.array([0, 0, -0.30]))
    with pytest.raises(LimbStructureError):
        LimbIK(robot, "right_leg")
    LimbIK(robot, "right_arm")  # untouched limb still fine


# ------------------------------------------------------------------ random round trips
@pytest.mark.parametrize("limb", LIMBS)
def test_fk_matches_pinocchio(robot, iks, limb):
    s = sampled_poses(robot, limb)
    p, R = iks[limb].fk(s["root_p"], s["root_R"], s["q"])
    assert np.abs(p - s["tip_p"]).max() < 1e-12
    assert rot_angle(R, s["tip_R"]).max() < 1e-12


@pytest.mark.parametrize("limb", LIMBS)
def test_random_round_trip(robot, iks, limb):
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    res = ik.solve(s["root_p"], s["root_R"], s["tip_p"], s["tip_R"])
    assert res.q.shape == (N_RANDOM, 6) and res.ok.shape == (N_RANDOM,)
    # every pose made from in-limit joint angles is solvable (no exclusions needed)
    assert res.ok.all(), res.failure_counts()
    assert np.all(res.reason == IKReason.OK) and np.all(res.branch >= 0)
    assert np.all(res.q >= ik.lower) and np.all(res.q <= ik.upper)
    p, R = ik.fk(s["root_p"], s["root_R"], res.q)
    assert np.linalg.norm(p - s["tip_p"], axis=1).max() < POS_TOL
    assert rot_angle(R, s["tip_R"]).max() < ROT_TOL


@pytest.mark.parametrize("limb", LIMBS)
def test_round_trip_checked_by_pinocchio(robot, iks, limb):
    """Independent check of FK(IK(x)) == x with pinocchio's own FK (subset)."""
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    idx = np.arange(0, N_RANDOM, 50)
    res = ik.solve(s["root_p"][idx], s["root_R"][idx], s["tip_p"][idx], s["tip_R"][idx])
    spec = robot.limbs[limb]
    d = robot.model.createData()
    ft = robot.frame_id(spec.tip)
    for k, i in enumerate(idx):
        q = s["Q"][i].copy()
        q[7 + np.array(spec.joint_index)] = res.q[k]
        pin.framesForwardKinematics(robot.model, d, q)
        assert np.linalg.norm(d.oMf[ft].translation - s["tip_p"][i]) < POS_TOL
        assert rot_angle(d.oMf[ft].rotation[None], s["tip_R"][i][None])[0] < ROT_TOL


@pytest.mark.parametrize("limb", LIMBS)
def test_q_ref_selects_sampled_branch(robot, iks, limb):
    """With the sampled angles as reference the IK returns them (away from the
    measure-zero singular sets, where the solution is not unique)."""
    s = sampled_poses(robot, limb)
    res = iks[limb].solve(s["root_p"], s["root_R"], s["tip_p"], s["tip_R"], q_ref=s["q"])
    same = np.abs(res.q - s["q"]).max(axis=1) < 1e-6
    assert same.mean() > 0.999


@pytest.mark.parametrize("limb", LIMBS)
def test_single_pose_path_matches_batch(robot, iks, limb):
    """N = 1 takes a pure-Python path (speed); it must agree with the numpy batch."""
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    idx = np.arange(0, N_RANDOM, 10)
    args = [s[k][idx] for k in ("root_p", "root_R", "tip_p", "tip_R")]
    q_refs = (None, s["q"][idx], np.zeros((len(idx), 6)))
    for q_ref in q_refs:
        batch = ik.solve(*args, q_ref=q_ref)
        q_one = np.empty((len(idx), 6))
        for k in range(len(idx)):
            one = ik.solve(*(a[k] for a in args), q_ref=None if q_ref is None else q_ref[k])
            assert one.ok[0] == batch.ok[k] and one.reason[0] == batch.reason[k]
            q_one[k] = one.q[0]
        # same branch; angles agree to round-off amplified by the conditioning
        # (near-stretched arms: ~1e-9)
        assert np.abs(q_one - batch.q).max() < 1e-6
        assert np.all(q_one >= ik.lower) and np.all(q_one <= ik.upper)
        p, R = ik.fk(args[0], args[1], q_one)
        assert np.linalg.norm(p - args[2], axis=1).max() < POS_TOL
        assert rot_angle(R, args[3]).max() < ROT_TOL


# ------------------------------------------------------------------ special poses
def test_half_sitting_round_trip(robot, iks):
    q = robot.half_sitting()
    for limb in LIMBS:
        spec = robot.limbs[limb]
        root, tip = robot.frame_pose(q, spec.root), robot.frame_pose(q, spec.tip)
        res = iks[limb].solve_se3(root, tip)
        assert res.ok[0]
        assert np.abs(res.q[0] - robot.half_sitting_joints[list(spec.joint_index)]).max() < 1e-9
        # the half-sitting is the default reference: same answer with it explicit
        res2 = iks[limb].solve_se3(root, tip, q_ref=iks[limb].q_default)
        assert np.array_equal(res.q, res2.q)


SINGULAR = {
    # (limb, degrees): stretched limbs, gimbal lock of the shoulder, wrist-pitch
    # branches merging (wrist yaw 90 deg), combinations of these
    "legs_straight": ("right_leg", [0, 0, 0, 0, 0, 0]),
    "leg_straight_tilted": ("right_leg", [10, -20, 30, 0, 40, 10]),
    "arm_straight": ("right_arm", [0, 0, 0, 0, 0, 0]),
    "arm_straight_twisted": ("right_arm", [10, -20, 30, 0, 40, 10]),
    "arm_tpose_gimbal": ("right_arm", [0, -90, 0, 0, 0, 0]),
    "arm_gimbal_bent": ("right_arm", [30, -90, 20, -40, 30, 10]),
    "wrist_yaw_90": ("right_arm", [10, -20, 30, -50, 90, 10]),
    "left_wrist_yaw_m90": ("left_arm", [10, 20, 30, -50, -90, 10]),
    "gimbal_and_straight": ("right_arm", [-45, -90, 0, 0, 20, 30]),
    # only q0 + q2 (gimbal) or q2 + q4 (stretched) is determined, and the default
    # split (free angle from the half-sitting reference) would violate a limit
    "gimbal_needs_split": ("right_arm", [55, -90, 85, -30, 10, 0]),
    "left_gimbal_needs_split": ("left_arm", [-170, 90, -85, -30, 10, 0]),
    "straight_needs_split": ("right_arm", [-30, -40, 85, 0, 85, 20]),
    "straight_tangent_wrist": ("left_arm", [-30, 40, 85, 0, -90, 20]),
}


@pytest.mark.parametrize("case", sorted(SINGULAR))
def test_singular_poses_round_trip(iks, case):
    limb, deg = SINGULAR[case]
    ik = iks[limb]
    rng = np.random.default_rng(7)
    root_R = random_rotations(rng, 1)[0]
    root_p = rng.uniform(-1, 1, 3)
    tip_p, tip_R = ik.fk(root_p, root_R, np.radians(deg))
    for q_ref in (None, np.zeros(6), np.radians(deg)):
        res = ik.solve(root_p, root_R, tip_p, tip_R, q_ref=q_ref)
        assert res.ok[0], (case, res.reason)
        # the numpy batch path (N = 2) gives the same answer as the N = 1 path
        res2 = ik.solve(np.stack([root_p] * 2), np.stack([root_R] * 2), np.concatenate([tip_p] * 2),
                        np.concatenate([tip_R] * 2), q_ref=q_ref)
        assert res2.ok.all() and np.abs(res2.q - res.q).max() < 1e-9
        p, R = ik.fk(root_p, root_R, res.q)
        assert np.linalg.norm(p - tip_p, axis=1)[0] < POS_TOL
        assert rot_angle(R, tip_R)[0] < ROT_TOL
        assert np.all(res.q >= ik.lower) and np.all(res.q <= ik.upper)


# ------------------------------------------------------------------ failures
@pytest.mark.parametrize("limb", LIMBS)
def test_beyond_reach_is_unreachable(robot, iks, limb):
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    n = 1000
    # push the tip away from the first joint centre so that it is 1 cm .. 1 m beyond
    # the limb length (l1 + l2 + |tip offset| bounds the reach of the tip point)
    c = s["root_p"][:n] + np.einsum("nij,j->ni", s["root_R"][:n], ik.t0)
    d = s["tip_p"][:n] - c
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    reach = abs(ik.l1) + abs(ik.l2) + np.linalg.norm(ik.te)
    dist = reach + np.random.default_rng(3).uniform(0.01, 1.0, n)
    res = ik.solve(s["root_p"][:n], s["root_R"][:n], c + dist[:, None] * u, s["tip_R"][:n])
    assert not res.ok.any()
    assert np.all(res.reason == IKReason.UNREACHABLE)
    assert np.isnan(res.q).all()
    assert res.failure_counts()["UNREACHABLE"] == n


@pytest.mark.parametrize("limb", LIMBS)
def test_slightly_beyond_reach_not_clipped(iks, limb):
    """Fully stretched limb: exact pose solvable, 1e-9 m .. 1e-6 m further is not."""
    ik = iks[limb]
    tip_p, tip_R = ik.fk(np.zeros(3), np.eye(3), np.zeros(6))
    assert ik.solve(np.zeros(3), np.eye(3), tip_p, tip_R).ok[0]
    for extra in (1e-9, 1e-8, 1e-6):
        res = ik.solve(np.zeros(3), np.eye(3), tip_p - [0, 0, extra], tip_R)
        assert not res.ok[0] and res.reason[0] == IKReason.UNREACHABLE
        assert np.isnan(res.q).all()


def test_impossible_hand_orientation_unreachable(iks):
    """Wrist centre on the wrist-pitch axis, 0.4 m from the shoulder: the wrist-yaw
    axis can never pass through it (|r_y| > U |sin q3|), whatever the joint limits."""
    ik = iks["right_arm"]
    c = ik.t0
    w = c - np.array([0.0, 0.4, 0.0])
    res = ik.solve(np.zeros(3), np.eye(3), w + ik.te, np.eye(3))
    assert res.reason[0] == IKReason.UNREACHABLE and np.isnan(res.q).all()


@pytest.mark.parametrize("limb", LIMBS)
def test_joint_limit_failures(robot, iks, limb):
    """Tip rotated 170 deg about its vertical: geometrically reachable, not within limits."""
    ik = iks[limb]
    q = robot.half_sitting()
    spec = robot.limbs[limb]
    root, tip = robot.frame_pose(q, spec.root), robot.frame_pose(q, spec.tip)
    Rz = pin.rpy.rpyToMatrix(0.0, 0.0, np.radians(170.0))
    res = ik.solve(root.translation, root.rotation, tip.translation, tip.rotation @ Rz)
    assert not res.ok[0] and res.reason[0] == IKReason.JOINT_LIMITS
    assert np.isnan(res.q).all() and res.branch[0] == -1
    # elbow bent forwards by 60 deg with the shoulder pitched back by 40 deg: the only other
    # branch reaching the same pose needs shoulder pitch 40 + 60 = 100 deg > 60 deg (limit)
    bent = np.zeros(6)
    bent[0], bent[3] = np.radians(40.0), np.radians(60.0)
    if ik.kind == "arm":
        res = ik.solve(np.zeros(3), np.eye(3), *ik.fk(np.zeros(3), np.eye(3), bent))
        assert res.reason[0] == IKReason.JOINT_LIMITS


def test_mixed_batch_and_invalid_input(iks):
    ik = iks["left_leg"]
    tip_p, tip_R = ik.fk(np.zeros(3), np.eye(3), ik.q_default)
    tip_ps = np.repeat(tip_p, 5, axis=0)
    tip_Rs = np.repeat(tip_R, 5, axis=0)
    tip_ps[1] = [0.0, 0.0, -2.0]                           # unreachable
    tip_Rs[2] = tip_Rs[2] @ pin.rpy.rpyToMatrix(0, 0, np.pi)  # joint limits
    tip_ps[3, 0] = np.nan                                  # invalid
    tip_Rs[4] = 2.0 * tip_Rs[4]                             # not a rotation
    res = ik.solve(np.zeros(3), np.eye(3), tip_ps, tip_Rs)
    assert res.ok.tolist() == [True, False, False, False, False]
    assert res.reason.tolist() == [0, 1, 2, 3, 3]
    assert np.isnan(res.q[1:]).all() and np.isfinite(res.q[0]).all()
    assert res.failure_counts() == {"UNREACHABLE": 1, "JOINT_LIMITS": 1, "INVALID_INPUT": 2}
    assert res.n_failed == 4 and len(res) == 5
    # the same one at a time (single-pose path)
    for k in range(5):
        one = ik.solve(np.zeros(3), np.eye(3), tip_ps[k], tip_Rs[k])
        assert one.reason[0] == res.reason[k]
    for bad in (np.inf, -np.inf, np.nan):
        p = tip_p[0].copy()
        p[2] = bad
        assert ik.solve(np.zeros(3), np.eye(3), p, tip_R[0]).reason[0] == IKReason.INVALID_INPUT
        assert ik.solve(np.zeros(3), np.eye(3), tip_p[0], tip_R[0], q_ref=np.full(6, bad)).reason[0] == 3
    mirror = tip_R[0] @ np.diag([1.0, 1.0, -1.0])                  # orthonormal, det -1
    assert ik.solve(np.zeros(3), np.eye(3), tip_p[0], mirror).reason[0] == IKReason.INVALID_INPUT
    assert ik.solve(np.zeros((2, 3)), np.eye(3), tip_ps[:2], np.stack([mirror] * 2)).reason.tolist() == [3, 3]


def test_single_pose_and_broadcasting(iks):
    ik = iks["right_arm"]
    q = ik.q_default
    tip_p, tip_R = ik.fk(np.zeros(3), np.eye(3), q)
    res = ik.solve(np.zeros(3), np.eye(3), tip_p[0], tip_R[0])   # all single: N = 1
    assert res.q.shape == (1, 6) and res.ok.shape == (1,)
    assert np.abs(res.q[0] - q).max() < 1e-12
    # one root pose, many tips; q_ref per row
    tips_p, tips_R = ik.fk(np.zeros(3), np.eye(3), np.tile(q, (4, 1)))
    res = ik.solve(np.zeros(3), np.eye(3), tips_p, tips_R, q_ref=np.tile(q, (4, 1)))
    assert res.q.shape == (4, 6) and res.ok.all()
    with pytest.raises(ValueError):
        ik.solve(np.zeros((2, 3)), np.eye(3), tips_p, tips_R)
    with pytest.raises(ValueError):
        ik.solve(np.zeros(3), np.eye(3), np.zeros((4, 2)), tips_R)


# ------------------------------------------------------------------ compiled legs vs reference
LEGS = ("right_leg", "left_leg")
EQ_TOL = 1e-12        # rad: compiled kernel vs numpy reference
EQ_TOL_ILL = 1e-9     # rad: the same near a singularity
EQ_FRACTION = 0.999   # rows that must agree to EQ_TOL


def assert_same_as_reference(ik: LimbIK, args, q_ref=None, same_branch: bool = True) -> None:
    """The compiled leg kernel gives the numpy reference's outcome: same ok / reason
    (/ branch) for every row, angles within EQ_TOL for >= 99.9% of the rows and within
    EQ_TOL_ILL for all. (The two differ by round-off in the products (BLAS/einsum vs
    scalar loops), ~1e-16; an angle near a singularity -- knee almost stretched, hip
    almost on the ankle-roll axis -- amplifies that by its conditioning: measured up to
    3e-11 at a knee of 2e-5 rad, on 4 of 10,000 random poses.)"""
    a = ik.solve(*args, q_ref=q_ref)
    b = ik.solve_reference(*args, q_ref=q_ref)
    assert np.array_equal(a.ok, b.ok)
    assert np.array_equal(a.reason, b.reason)
    if same_branch:
        assert np.array_equal(a.branch, b.branch)
    assert np.array_equal(np.isnan(a.q), np.isnan(b.q))
    ok = a.ok
    if ok.any():
        diff = np.abs(a.q[ok] - b.q[ok]).max(axis=1)
        assert diff.max() <= EQ_TOL_ILL
        assert np.mean(diff <= EQ_TOL) >= (EQ_FRACTION if len(diff) >= 1000 else 1.0) or diff.max() <= EQ_TOL
        p, R = ik.fk(np.broadcast_to(np.asarray(args[0]).reshape(-1, 3), (len(a.q), 3))[ok],
                     np.broadcast_to(np.asarray(args[1]).reshape(-1, 3, 3), (len(a.q), 3, 3))[ok], a.q[ok])
        tip_p = np.broadcast_to(np.asarray(args[2]).reshape(-1, 3), (len(a.q), 3))[ok]
        tip_R = np.broadcast_to(np.asarray(args[3]).reshape(-1, 3, 3), (len(a.q), 3, 3))[ok]
        assert np.linalg.norm(p - tip_p, axis=1).max() < POS_TOL
        assert rot_angle(R, tip_R).max() < ROT_TOL


def test_leg_ik_is_compiled_and_reference_is_numpy(robot):
    ik = LimbIK(robot, "right_leg")
    assert ik.compiled and not LimbIK(robot, "right_leg", compiled=False).compiled
    assert not LimbIKSet(robot, compiled=False)["left_leg"].compiled
    s = sampled_poses(robot, "right_leg")
    args = [s[k][:50] for k in ("root_p", "root_R", "tip_p", "tip_R")]
    ref = LimbIK(robot, "right_leg", compiled=False)
    # solve_reference == the non-compiled solver, bit for bit
    assert np.array_equal(ik.solve_reference(*args).q, ref.solve(*args).q)


@pytest.mark.parametrize("limb", LEGS)
def test_compiled_leg_ik_matches_reference(robot, iks, limb):
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    args = [s[k] for k in ("root_p", "root_R", "tip_p", "tip_R")]
    rng = np.random.default_rng(11)
    q_rand = rng.uniform(ik.lower, ik.upper, (N_RANDOM, 6))
    for q_ref in (None, s["q"], q_rand, ik.q_default):
        assert_same_as_reference(ik, args, q_ref)
    # single poses (the reference takes its pure-Python path for N = 1)
    for k in range(0, N_RANDOM, 500):
        assert_same_as_reference(ik, [a[k] for a in args], q_rand[k])
    # one root pose, many tips (broadcast rows) and one tip, many roots
    assert_same_as_reference(ik, [args[0][0], args[1][0], args[2][:200], args[3][:200]])
    assert_same_as_reference(ik, [args[0][:200], args[1][:200], args[2][0], args[3][0]])


@pytest.mark.parametrize("limb", LEGS)
def test_compiled_leg_ik_failures_match_reference(robot, iks, limb):
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    n = 2000
    root_p, root_R = s["root_p"][:n].copy(), s["root_R"][:n].copy()
    tip_p, tip_R = s["tip_p"][:n].copy(), s["tip_R"][:n].copy()
    rng = np.random.default_rng(5)
    tip_p += rng.normal(scale=0.3, size=tip_p.shape)                 # many beyond reach
    tip_R[::7] = tip_R[::7] @ random_rotations(rng, len(tip_R[::7]))  # many outside the limits
    tip_p[3, 1] = np.nan
    root_p[4, 0] = np.inf
    tip_R[5] = 2.0 * tip_R[5]
    root_R[6] = root_R[6] @ np.diag([1.0, 1.0, -1.0])
    res = ik.solve(root_p, root_R, tip_p, tip_R)
    counts = res.failure_counts()
    assert counts["UNREACHABLE"] > 100 and counts["JOINT_LIMITS"] > 10 and counts["INVALID_INPUT"] == 4
    assert_same_as_reference(ik, [root_p, root_R, tip_p, tip_R])
    assert_same_as_reference(ik, [root_p, root_R, tip_p, tip_R], np.full(6, np.nan))   # NaN reference: invalid


@pytest.mark.parametrize("deg", [[0, 0, 0, 0, 0, 0], [10, -20, 30, 0, 40, 10], [20, 90, -10, 50, -30, 5],
                                 [-15, -90, 25, 60, -20, -5], [5, 3, -8, 1e-4, 2, 1]])
@pytest.mark.parametrize("limb", LEGS)
def test_compiled_leg_ik_singular_poses_match_reference(iks, limb, deg):
    """Stretched knee, hip gimbal lock (roll +-90 deg: redistribution of q0/q2, mostly
    out of the limits), nearly stretched: the same outcome as the reference (the branch
    index may differ where two branches coincide)."""
    ik = iks[limb]
    rng = np.random.default_rng(3)
    root_R = random_rotations(rng, 1)[0]
    root_p = rng.uniform(-1, 1, 3)
    tip_p, tip_R = ik.fk(root_p, root_R, np.radians(deg))
    for q_ref in (None, np.zeros(6), np.radians(deg)):
        assert_same_as_reference(ik, [root_p, root_R, tip_p, tip_R], q_ref, same_branch=False)
        assert_same_as_reference(ik, [np.stack([root_p] * 3), root_R, np.concatenate([tip_p] * 3), tip_R], q_ref,
                                 same_branch=False)


@pytest.mark.parametrize("limb", LIMBS)
def test_maybe_reachable_never_rejects_a_solvable_pose(robot, iks, limb):
    """The goal sampler's prefilter: False only where solve fails (random poses, poses
    pushed around the reach boundary, the stretched limb)."""
    ik = iks[limb]
    s = sampled_poses(robot, limb)
    rng = np.random.default_rng(11)
    n = 1500
    c = s["root_p"][:n] + np.einsum("nij,j->ni", s["root_R"][:n], ik.t0)
    d = s["tip_p"][:n] - c
    # scale the tip distance by 0.5 .. 1.5 (many poses just inside / outside the reach)
    tips = c + d * rng.uniform(0.5, 1.5, n)[:, None]
    for tip_p in (s["tip_p"][:n], tips):
        res = ik.solve(s["root_p"][:n], s["root_R"][:n], tip_p, s["tip_R"][:n])
        may = ik.maybe_reachable(s["root_p"][:n], s["root_R"][:n], tip_p, s["tip_R"][:n])
        assert may.shape == (n,)
        assert not np.any(res.ok & ~may)
        assert not np.any(~may & (res.reason != IKReason.UNREACHABLE) & (res.reason != IKReason.INVALID_INPUT))
    assert 0 < np.count_nonzero(~may) < n   # the boundary set has both sides
    tip_p, tip_R = ik.fk(np.zeros(3), np.eye(3), np.zeros(6))
    assert ik.maybe_reachable(np.zeros(3), np.eye(3), tip_p, tip_R)[0]
    assert not ik.maybe_reachable(np.zeros(3), np.eye(3), [np.nan, 0, 0], tip_R)[0]
