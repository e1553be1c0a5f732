"""The numerical limb IK (kinematics/numerical_ik.py, issue 23) on the Unitree G1's four limbs,
which no closed form of the package solves (offsets between all their axes): poses from the
FK of random joints are solved exactly within the limits, a reference next to the answer
keeps it (6R: the same joints), poses beyond the reach bound and non-finite input are not
ok, and the reach bound GeneralLimb gives such a chain is conservative. On Talos's limbs the
numerical solver agrees with the closed form. GeneralLimb picks the numerical solver for
G1's limbs and keeps the closed forms for HRP-2's and Talos's.

No G1 robot description exists yet: the pinocchio model is built from the URDF of
example-robot-data (free-flyer root), with a tiny adapter for what Chain6.from_model and
GeneralLimb read."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from humanoid_reach_ros.kinematics.general_ik import Chain6
from humanoid_reach_ros.kinematics.general_ik_compiled import CompiledGeneralLimbIK, CompiledRedundantLimbIK
from humanoid_reach_ros.kinematics.general_limb import GeneralLimb
from humanoid_reach_ros.kinematics.hand_derived import LimbIK
from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import LimbSpec, RobotModel
from humanoid_reach_ros.kinematics.numerical_ik import NumericalLimbIK, warm_up

N_POSES = 500
EXACT = 1e-9          # [m], [rad]: the answers reach their poses this well

G1_LIMBS = {
    "left_leg": ("pelvis", [f"left_{j}_joint" for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch",
                                                         "ankle_roll")], "left_ankle_roll_link"),
    "right_leg": ("pelvis", [f"right_{j}_joint" for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch",
                                                           "ankle_roll")], "right_ankle_roll_link"),
    "left_arm": ("torso_link", [f"left_{j}_joint" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow",
                                                            "wrist_roll", "wrist_pitch", "wrist_yaw")],
                 "left_wrist_yaw_link"),
    "right_arm": ("torso_link", [f"right_{j}_joint" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw",
                                                              "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw")],
                  "right_wrist_yaw_link"),
}


def _g1_urdf() -> Path:
    import cmeel

    return Path(cmeel.__path__[0]).parent / "cmeel.prefix/share/example-robot-data/robots/g1_description/urdf/" \
        "g1_29dof_rev_1_0.urdf"


class G1:
    """What Chain6.from_model and GeneralLimb read of a RobotModel: ``model``, ``joint_index``,
    ``lower`` / ``upper``, ``limbs`` and ``half_sitting_joints`` (all zero)."""

    def __init__(self) -> None:
        self.model = m = pin.buildModelFromUrdf(str(_g1_urdf()), pin.JointModelFreeFlyer())
        self.joint_index = {m.names[j]: m.joints[j].idx_q - 7 for j in range(2, m.njoints)}
        self.lower = m.lowerPositionLimit[7:].copy()
        self.upper = m.upperPositionLimit[7:].copy()
        self.half_sitting_joints = np.zeros(m.nq - 7)
        self.limbs = {name: LimbSpec(name, root, tip, tuple(joints), tuple(self.joint_index[j] for j in joints))
                      for name, (root, joints, tip) in G1_LIMBS.items()}

    def chain(self, limb: str) -> Chain6:
        s = self.limbs[limb]
        return Chain6.from_model(self, s.root, s.joints, s.tip)


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up()


@pytest.fixture(scope="module")
def g1():
    return G1()    # a shipped robot: an error building it fails the tests, never skips them


@pytest.fixture(scope="module")
def solvers(g1):
    out = {}
    for limb in G1_LIMBS:
        c = g1.chain(limb)
        out[limb] = (c, NumericalLimbIK(c, np.clip(np.zeros(len(c.axes)), c.lower, c.upper)))
    return out


def rot_angle(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle of Ra^T Rb (atan2 form, accurate near 0)."""
    D = np.einsum("nji,njk->nik", Ra, Rb)
    skew = np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=1), 0.5 * (np.trace(D, axis1=1, axis2=2) - 1.0))


def _reach_bound(c: Chain6) -> float:
    return float(np.sum(np.linalg.norm(c.t[1:], axis=1)))


def _centre_distance(c: Chain6, P, R) -> np.ndarray:
    """Distance from joint 1's origin to the last joint's origin, for tip poses (P, R)."""
    return np.linalg.norm(P - R @ (c.Re.T @ c.te) - c.t[0], axis=1)


def _reached(c: Chain6, q, P, R):
    p2, R2 = c.fk(q)
    return np.linalg.norm(p2 - P, axis=1), rot_angle(R2, R)


# ------------------------------------------------------------------ G1
def test_g1_limbs_are_outside_the_closed_forms(g1):
    for limb in G1_LIMBS:
        c = g1.chain(limb)
        with pytest.raises(ValueError):
            (CompiledRedundantLimbIK if len(c.axes) == 7 else CompiledGeneralLimbIK)(c, np.zeros(len(c.axes)))


@pytest.mark.parametrize("limb", list(G1_LIMBS))
def test_random_poses_are_solved_exactly(solvers, limb):
    c, ik = solvers[limb]
    n = len(c.axes)
    rng = np.random.default_rng(23)
    q = rng.uniform(c.lower, c.upper, (N_POSES, n))
    P, R = c.fk(q)
    res = ik.solve(P, R)
    assert res.ok.dtype == np.bool_ and res.q.shape == (N_POSES, n)
    assert res.ok.mean() >= 0.98, res.ok.mean()
    qa = res.q[res.ok]
    assert np.all((qa >= c.lower) & (qa <= c.upper))
    ep, eR = _reached(c, qa, P[res.ok], R[res.ok])
    assert ep.max() < EXACT and eR.max() < EXACT
    assert np.isnan(res.q[~res.ok]).all()
    # the reach bound is conservative: every pose (all are reachable) within it
    assert _centre_distance(c, P, R).max() <= _reach_bound(c)
    # solve_one gives solve's answers
    for i in range(5):
        ok, q1 = ik.solve_one(P[i], R[i])
        assert ok == res.ok[i]
        np.testing.assert_array_equal(q1, res.q[i])


@pytest.mark.parametrize("limb", list(G1_LIMBS))
def test_a_reference_next_to_the_answer_keeps_it(solvers, limb):
    c, ik = solvers[limb]
    n = len(c.axes)
    rng = np.random.default_rng(7)
    q = rng.uniform(c.lower, c.upper, (N_POSES, n))
    P, R = c.fk(q)
    ref = q + rng.uniform(-0.05, 0.05, q.shape)
    res = ik.solve(P, R, ref)
    assert res.ok.all()
    ep, eR = _reached(c, res.q, P, R)
    assert ep.max() < EXACT and eR.max() < EXACT
    dq = np.abs(res.q - q).max(axis=1)
    if n == 6:    # the solution is locally unique: the same joints
        assert dq.max() < 0.1, dq.max()
    else:         # the redundant arm: near them (the self-motion may drift at a near-singular configuration)
        assert np.median(dq) < 0.05 and np.mean(dq < 0.1) >= 0.95, (np.median(dq), np.mean(dq < 0.1))


@pytest.mark.parametrize("limb", list(G1_LIMBS))
def test_beyond_the_reach_bound_and_non_finite_input_are_not_ok(solvers, limb):
    c, ik = solvers[limb]
    n = len(c.axes)
    rng = np.random.default_rng(3)
    m = 40
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    R = c.fk(rng.uniform(c.lower, c.upper, (m, n)))[1]
    centre = c.t[0] + (_reach_bound(c) + 0.5) * d
    P = centre + R @ (c.Re.T @ c.te)
    res = ik.solve(P, R)
    assert not res.ok.any() and np.isnan(res.q).all()
    # non-finite input: not ok, no exception
    p0, R0 = c.fk(np.clip(np.zeros((1, n)), c.lower, c.upper))
    bad_p, bad_R = p0.repeat(3, 0), R0.repeat(3, 0)
    bad_p[0, 1] = np.nan
    bad_R[1, 2, 0] = np.inf
    bad_p[2, 0] = -np.inf
    res = ik.solve(bad_p, bad_R)
    assert not res.ok.any() and np.isnan(res.q).all()
    ok, q1 = ik.solve_one(bad_p[0], bad_R[0])
    assert not ok and np.isnan(q1).all()
    # a non-finite reference is replaced by the default one
    ok, q1 = ik.solve_one(p0[0], R0[0], np.full(n, np.nan))
    assert ok and np.isfinite(q1).all()


def test_general_limb_picks_the_numerical_solver_for_g1(g1):
    rng = np.random.default_rng(11)
    for limb in G1_LIMBS:
        lk = GeneralLimb(g1, limb)
        c = lk.chain
        assert lk.kind == "numerical" and isinstance(lk.ik, NumericalLimbIK) and lk.compiled is False
        assert lk.n_joints == len(c.axes)
        assert lk.l1 + lk.l2 == pytest.approx(_reach_bound(c)) and abs(lk.l1 - lk.l2) == 0.0
        pts, slack, reach = lk.reach_centres()
        np.testing.assert_array_equal(pts, c.t[0][None])
        assert slack == 0.0 and reach == pytest.approx(lk.l1 + lk.l2)
        np.testing.assert_array_equal(lk.te, c.te)
        np.testing.assert_array_equal(lk.Re, c.Re)
        # the limb protocol on world poses: a root somewhere, tips from the FK
        root_p = np.array([0.1, -0.2, 0.8])
        root_R = pin.rpy.rpyToMatrix(0.1, -0.2, 0.3)
        q = rng.uniform(c.lower, c.upper, (50, len(c.axes)))
        tip_p, tip_R = lk.fk(root_p, root_R, q)
        assert lk.maybe_reachable(root_p, root_R, tip_p, tip_R).all()
        res = lk.solve(root_p, root_R, tip_p, tip_R, q)
        assert res.ok.all()
        p2, R2 = lk.fk(root_p, root_R, res.q)
        assert np.abs(p2 - tip_p).max() < EXACT and rot_angle(R2, tip_R).max() < EXACT
        d = rng.normal(size=(50, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        far = root_p + (c.t[0] + (lk.l1 + lk.l2 + 0.5) * d) @ root_R.T + tip_R @ (lk.Re.T @ lk.te)
        assert not lk.maybe_reachable(root_p, root_R, far, tip_R).any()
        assert not lk.solve(root_p, root_R, far, tip_R).ok.any()


def test_hrp2_and_talos_keep_their_kinds():
    hrp2, talos = RobotModel("hrp2"), RobotModel("talos")
    for limb in ("right_leg", "left_leg", "right_arm", "left_arm"):
        assert GeneralLimb(hrp2, limb).kind == "general"
        assert isinstance(LimbIKSet(hrp2)[limb], LimbIK)
    talos_set = LimbIKSet(talos)
    for limb in ("right_leg", "left_leg"):
        assert GeneralLimb(talos, limb).kind == "general"
        assert isinstance(talos_set[limb], LimbIK)
    for limb in ("right_arm", "left_arm"):
        assert GeneralLimb(talos, limb).kind == "redundant"
        assert isinstance(talos_set[limb], GeneralLimb) and talos_set[limb].kind == "redundant"


# ------------------------------------------------------------------ against a closed form
def _talos_limb(talos, limb):
    spec = talos.limbs[limb]
    chain = Chain6.from_model(talos, spec.root, spec.joints, spec.tip)
    q_default = np.clip(np.asarray(talos.half_sitting_joints)[list(spec.joint_index)], chain.lower, chain.upper)
    return chain, q_default


def test_talos_solved_numerically_agrees_with_the_closed_form():
    talos = RobotModel("talos")
    rng = np.random.default_rng(5)
    for limb in ("right_leg", "right_arm"):
        chain, q_default = _talos_limb(talos, limb)
        n = len(chain.axes)
        closed = (CompiledRedundantLimbIK if n == 7 else CompiledGeneralLimbIK)(chain, q_default)
        num = NumericalLimbIK(chain, q_default)
        q = rng.uniform(chain.lower, chain.upper, (300, n))
        P, R = chain.fk(q)
        a, b = closed.solve(P, R), num.solve(P, R)
        assert a.ok.mean() > 0.9
        # the numerical solver reaches (nearly) every pose the closed form reaches, exactly
        assert b.ok[a.ok].mean() >= 0.97, b.ok[a.ok].mean()
        ep, eR = _reached(chain, b.q[b.ok], P[b.ok], R[b.ok])
        assert ep.max() < EXACT and eR.max() < EXACT
        if n == 6:   # a reference next to the closed form's answer: its joints
            ref = a.q[a.ok] + rng.uniform(-0.02, 0.02, (int(a.ok.sum()), n))
            c = num.solve(P[a.ok], R[a.ok], ref)
            assert c.ok.all()
            np.testing.assert_allclose(c.q, a.q[a.ok], atol=1e-6)
