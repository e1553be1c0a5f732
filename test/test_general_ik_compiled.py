"""The compiled general closed-form IK (kinematics/general_ik_compiled.py) gives its numpy reference's
answers (kinematics/general_ik.py): the same ``ok`` and the same joints where ok, on Talos's 7-DOF
arms (RedundantLimbIK, the subchain in the direct form) and legs, HRP-2's four limbs (6R,
reversed form), the 7R arm's subchain on its own (6R, direct form) and random chains of the
class in both forms (test_general_ik.py's constructions); reachable poses from the FK of
random joints (default, drawn and random references), poses beyond reach, and poses with
joints within 1e-6 rad of their limits. The compiled answers reach their poses.

Not compared: joints exactly at a limit. Both implementations wrap a candidate into
``[lower, lower + 2 pi)``, so a candidate that lands 1e-16 below its lower limit wraps to the
far end and is dropped; which side of the limit rounding puts it on is not reproducible
between two orders of floating-point operations (nor is the FK check at an exactly
stretched elbow or knee, a singular configuration)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from humanoid_reach_ros.kinematics.general_ik import Chain6, GeneralLimbIK, RedundantLimbIK
from humanoid_reach_ros.kinematics.general_ik_compiled import (
    CompiledGeneralLimbIK, CompiledRedundantLimbIK, compiled_general_ik, warm_up,
)
from humanoid_reach_ros.robot.model import RobotModel
from test_general_ik import _random_chain   # the random 6R chain of the class, drawn the same way

Q_TOL = 1e-9          # random poses: the two orders of operations agree this well
Q_TOL_NEAR = 1e-7     # within 1e-6 of a limit (a knee or elbow that close to straight: ill-conditioned)
FK_ERR = 1e-8         # general_ik.FK_TOL


@pytest.fixture(scope="module", autouse=True)
def _compiled():
    warm_up()     # compiles once (or loads numba's cache) before the first timed test


@pytest.fixture(scope="module")
def robots():
    return {"hrp2": RobotModel("hrp2"), "talos": RobotModel("talos")}


def _limb(robot, limb, samples=16):
    """(reference, compiled) for a limb of ``robot``, built as GeneralLimb builds its solver."""
    spec = robot.limbs[limb]
    chain = Chain6.from_model(robot, spec.root, spec.joints, spec.tip)
    q_default = np.clip(np.asarray(robot.half_sitting_joints)[list(spec.joint_index)], chain.lower, chain.upper)
    if len(chain.axes) == 7:
        return RedundantLimbIK(chain, q_default, samples), CompiledRedundantLimbIK(chain, q_default, samples)
    return GeneralLimbIK(chain, q_default), CompiledGeneralLimbIK(chain, q_default)


def _same(ref, comp, P, R, q_ref=None, tol=Q_TOL):
    """The compiled answer is the reference's, and it reaches the poses; returns ok."""
    a, b = ref.solve(P, R, q_ref), comp.solve(P, R, q_ref)
    np.testing.assert_array_equal(b.ok, a.ok)
    assert b.q.shape == a.q.shape and b.ok.dtype == np.bool_
    np.testing.assert_allclose(b.q[a.ok], a.q[a.ok], atol=tol, rtol=0)
    assert np.isnan(b.q[~b.ok]).all()
    c = comp.chain
    q = b.q[b.ok]
    assert np.all((q >= c.lower) & (q <= c.upper))
    p2, R2 = c.fk(q)
    Rt = np.broadcast_to(np.asarray(R).reshape(-1, 3, 3), (len(b.ok), 3, 3))[b.ok]
    assert np.linalg.norm(p2 - np.atleast_2d(P)[b.ok], axis=1).max(initial=0) < FK_ERR
    assert np.linalg.norm((R2 - Rt).reshape(-1, 9), axis=1).max(initial=0) < FK_ERR
    return a.ok


def _pose_sets(chain, rng, n):
    """(name, P, R, q_ref, tol): reachable poses (three references), beyond reach, near limits."""
    lo, hi = chain.lower, chain.upper
    q = rng.uniform(lo, hi, (n, len(lo)))
    p, R = chain.fk(q)
    side = rng.integers(0, 3, q.shape)                     # 0 free, 1 near the lower limit, 2 near the upper
    q_near = np.where(side == 1, lo + 1e-6, np.where(side == 2, hi - 1e-6, q))
    p_near, R_near = chain.fk(q_near)
    far = p * rng.uniform(1.0, 1.3, (n, 1))
    return [("default reference", p, R, None, Q_TOL),
            ("the drawn joints as reference", p, R, q, Q_TOL),
            ("random references", p, R, rng.uniform(lo, hi, q.shape), Q_TOL),
            ("up to 30 % farther", far, R, None, Q_TOL),
            ("5 m away", p + 5.0, R, None, Q_TOL),
            ("near the limits", p_near, R_near, None, Q_TOL_NEAR),
            ("near the limits, drawn reference", p_near, R_near, q_near, Q_TOL_NEAR)]


@pytest.mark.parametrize("robot_name,limb,n", [
    ("talos", "right_arm", 160), ("talos", "left_arm", 100), ("talos", "right_leg", 300), ("talos", "left_leg", 300),
    ("hrp2", "right_arm", 300), ("hrp2", "left_arm", 300), ("hrp2", "right_leg", 300), ("hrp2", "left_leg", 300),
])
def test_robot_limbs_give_the_reference_answers(robots, robot_name, limb, n):
    ref, comp = _limb(robots[robot_name], limb)
    if len(comp.chain.axes) == 6:
        assert comp.reversed and comp.reversed == ref.reversed   # three intersecting axes at the root
    else:
        assert not comp.sub.reversed and comp._d_range is not None   # the distance pre-test applies
    rng = np.random.default_rng([len(robot_name), *map(ord, limb)])    # a seed per limb, fixed
    oks = {}
    for name, P, R, q_ref, tol in _pose_sets(comp.chain, rng, n):
        oks[name] = _same(ref, comp, P, R, q_ref, tol)
    assert oks["the drawn joints as reference"].all() and not oks["5 m away"].any()
    assert 0.0 < oks["up to 30 % farther"].mean() < 1.0


def test_the_seven_joint_arms_subchain_in_the_direct_form(robots):
    """Talos's arm without its first joint: a 6R chain with the wrist at its tip (not reversed)."""
    red, _ = _limb(robots["talos"], "right_arm")
    sub = red.sub.chain
    ref, comp = GeneralLimbIK(sub, red.q_default[1:]), CompiledGeneralLimbIK(sub, red.q_default[1:])
    assert not comp.reversed
    rng = np.random.default_rng(21)
    for _name, P, R, q_ref, tol in _pose_sets(sub, rng, 300):
        _same(ref, comp, P, R, q_ref, tol)


@pytest.mark.parametrize("wrist_at_tip", [True, False])
def test_random_chains_of_both_forms(wrist_at_tip):
    rng = np.random.default_rng(30 + wrist_at_tip)
    for _ in range(8):
        chain = _random_chain(rng, wrist_at_tip)
        chain = Chain6(chain.R, chain.t, chain.axes, chain.Re, chain.te, rng.uniform(-3.0, -0.5, 6),
                       rng.uniform(0.5, 3.0, 6))     # limits that cut the branches
        ref, comp = GeneralLimbIK(chain, np.zeros(6)), CompiledGeneralLimbIK(chain, np.zeros(6))
        assert comp.reversed is not wrist_at_tip
        for _name, P, R, q_ref, tol in _pose_sets(chain, rng, 100):
            _same(ref, comp, P, R, q_ref, tol)


@pytest.mark.parametrize("pretest", [True, False])
def test_random_seven_joint_arms(pretest):
    """test_general_ik.py's random 7R arm (shoulder 2-3 intersecting, spherical wrist 5-6-7: the
    subchain in the direct form, the distance pre-test applies), and one whose subchain is
    reversed (joints 2-3-4 intersecting, 6-7 too: no pre-test); 64 first-joint values."""
    rng = np.random.default_rng(11 + pretest)
    R = Rotation.random(7, random_state=5 + pretest).as_matrix()
    t = rng.uniform(-0.25, 0.25, size=(7, 3))
    if pretest:
        t[2] = t[5] = t[6] = 0.0
    else:
        t[2] = t[3] = t[6] = 0.0
    axes = rng.normal(size=(7, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    chain = Chain6(R, t, axes, np.eye(3), np.array([0.0, 0.0, 0.1]), np.full(7, -2.5), np.full(7, 2.5))
    ref, comp = RedundantLimbIK(chain, np.zeros(7), samples=64), CompiledRedundantLimbIK(chain, np.zeros(7), samples=64)
    assert (comp._d_range is not None) is pretest and comp.sub.reversed is not pretest
    oks = [_same(ref, comp, P, Rt, q_ref, tol) for _name, P, Rt, q_ref, tol in _pose_sets(chain, rng, 40)]
    assert oks[0].mean() > 0.5


def test_shapes_broadcasting_and_the_single_pose_call(robots):
    red, comp = _limb(robots["talos"], "left_arm")
    leg_ref, leg = _limb(robots["hrp2"], "right_leg")
    rng = np.random.default_rng(40)
    for ref, c in ((red, comp), (leg_ref, leg)):
        nj = len(c.chain.axes)
        q = rng.uniform(c.chain.lower, c.chain.upper, (5, nj))
        p, R = c.chain.fk(q)
        one = c.solve(p[0], R[0])                       # one pose: (3,), (3, 3)
        assert one.q.shape == (1, nj) and one.ok.shape == (1,)
        _same(ref, c, p[0], R[0])
        _same(ref, c, p, R[0])                          # one rotation for every position
        _same(ref, c, p, R, q[0])                       # one reference for every pose
        _same(ref, c, p, R[:, None], q)                 # (N, 1, 3, 3) reshaped as the reference does
        _same(ref, c, p.T.copy().T, np.broadcast_to(R[0], (5, 3, 3)), q[:, ::-1].copy()[:, ::-1])  # strided inputs
        for k in range(5):
            ok, qk = c.solve_one(p[k], R[k], q[k])
            whole = c.solve(p[k], R[k], q[k])
            assert ok == whole.ok[0] and np.array_equal(qk, whole.q[0], equal_nan=True)
        ok, qk = c.solve_one(p[0] + 5.0, R[0])
        assert not ok and np.isnan(qk).all()
        bad = p.copy()
        bad[1] = np.nan                                 # a NaN pose fails alone, as in the reference
        with np.errstate(invalid="ignore"):
            expected = ref.solve(bad, R, q).ok
        assert expected[0] and not expected[1]
        np.testing.assert_array_equal(c.solve(bad, R, q).ok, expected)
        with pytest.raises(ValueError):
            c.solve(p[:, :2], R)
        with pytest.raises(ValueError):
            c.solve(p, R, np.zeros(nj + 1))
        with pytest.raises(ValueError):
            c.solve_one(p[0], R[0], np.zeros(nj - 1))
    assert compiled_general_ik(comp.chain, comp.q_default).__class__ is CompiledRedundantLimbIK
    assert compiled_general_ik(leg.chain, leg.q_default).__class__ is CompiledGeneralLimbIK
    with pytest.raises(ValueError, match="not solvable in closed form"):
        t = leg.chain.t.copy()
        t[4] = [0.05, 0.0, 0.0]
        t[1] = [0.0, 0.05, 0.0]
        CompiledGeneralLimbIK(Chain6(leg.chain.R, t, leg.chain.axes, leg.chain.Re, leg.chain.te, leg.chain.lower,
                                     leg.chain.upper), np.zeros(6))


@settings(max_examples=30, deadline=None, derandomize=True)
@given(u=st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7), v=st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7),
       scale=st.floats(0.9, 1.15))
def test_property_any_pose_and_reference_of_a_seven_joint_arm(robots, u, v, scale):
    """Joints anywhere in the limits (hypothesis tries their ends too), the position scaled about
    the root, any reference: the same answer -- except where a joint sits exactly at a limit,
    where only the reached pose is checked (module docstring)."""
    ref, comp = _limb(robots["talos"], "right_arm")
    c = comp.chain
    q = c.lower + np.asarray(u) * (c.upper - c.lower)
    q_ref = c.lower + np.asarray(v) * (c.upper - c.lower)
    p, R = c.fk(q)
    p = p * scale
    at_limit = np.isin(u, (0.0, 1.0)).any()
    if not at_limit:
        _same(ref, comp, p, R, q_ref)
    else:
        b = comp.solve(p, R, q_ref)
        if b.ok[0]:
            p2, R2 = c.fk(b.q)
            assert np.linalg.norm(p2 - p) < FK_ERR and np.linalg.norm(R2 - R) < FK_ERR
