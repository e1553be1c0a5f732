"""Closed-form solution of Algorithm 3's lower-body problem (dissertation Sec. 4.3), compiled.

Algorithm 3 solves, numerically on the 12 leg joints with the support sole fixed,

    p_CoM(q_legs) = p*_CoM,   R_torso = R*_torso,   T_swing = T*_swing.

That is 12 equations in 12 unknowns. **Reformulation (named; same solution set, not the
paper's iteration):** once the waist (torso link ``base_link``) pose ``(p_w, R*_torso)`` is
given, both soles' poses are known (support: fixed; swing: its target), so each leg's six
angles follow in closed form from :func:`humanoid_reach_ros.kinematics.hand_derived.leg_ik_pose`
(the compiled Pieper solution, branch closest to the previous leg angles). The only
remaining unknown is the waist position ``p_w`` (3), fixed by the CoM equation

    f(p_w) = p_CoM(p_w) - p*_CoM = 0,
    p_CoM(p_w) = (m_up (p_w + R*_torso c_up) + sum_legs sum_k m_k (p_k + R_k c_k)) / M,

with ``c_up`` the CoM of everything above the hips in the waist frame (chest, arms and
head held at ``q_upperBody``, computed once per call from pinocchio's subtree CoMs) and
``m_k, c_k`` the leg links' masses and CoM levers (pinocchio ``model.inertias``, with the
fixed links merged). ``f`` is solved by Newton's method, the 3 x 3 Jacobian by forward
differences (``FD_STEP_M``; kept between calls and re-evaluated only when a step
reduces the residual by less than 10x), all in one numba kernel; the stopping test is Algorithm 3's
``|e| < tol`` (torso and swing rows of ``e`` are zero up to round-off by construction).

**Legs without a hand-derived closed form** (the Unitree G1's: the hip pitch, roll and yaw
axes miss each other by 2-3 cm): the same Newton on the waist position, each leg's six angles
from the numerical solver's tracking iteration instead (``kinematics/numerical_ik.py``
``numerical_ik_track``: damped least squares on the leg's chain from the previous step's angles,
then from the previous Newton iterate's, polished to 1e-12; **a named simplification**: a local
solve, no branch search, so a leg the iteration does not reach from there counts as failed and
the call falls back to Algorithm 3). The mass sums take each joint's axis as a vector
(``kind`` 0 / 1 per leg, the numerical constants ``KN``). Tests: test_g1_dual_arm.py.

When the closed form has no in-limit solution (a leg out of reach or beyond its limits)
or Newton does not converge within ``max_iter``, :class:`ClosedFormLowerBodyIK` falls back
to the numerical :class:`~humanoid_reach_ros.dual_arm.lower_body_ik.LowerBodyIK` (the
reference), so results and failure reports stay those of Algorithm 3. Tests check both
paths agree (test_whole_body_ik.py).

No rclpy here.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.dual_arm.lower_body_ik import LowerBodyIK, LowerBodyResult
from humanoid_reach_ros.kinematics import (LEG_WORK_SIZE, LimbIK, LimbStructureError, chain_axis_rotation as _rot,
                                           leg_ik_pose, limb_solver, numerical_ik_track, numerical_leg_constants,
                                           numerical_work_size)
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel

_JIT = dict(cache=True, nogil=False, fastmath=False)
#: forward-difference step of the CoM Jacobian d p_CoM / d p_w [m]
FD_STEP_M = 1e-6
_AXIS = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@nb.njit(**_JIT)
def _leg_mass_moment(p, R, q, chain_t, chain_R, axes, mass, lever, acc, scratch):
    """Adds ``sum_k m_k (p_k + R_k c_k)`` of one leg to ``acc`` (3,); the leg's root
    (waist) pose ``(p, R)``, joints ``q`` (6,). ``scratch`` (4, 3, 3)."""
    Rc = scratch[0]
    T = scratch[1]
    Rr = scratch[2]
    pc = scratch[3, 0]
    for a in range(3):
        pc[a] = p[a]
        for b in range(3):
            Rc[a, b] = R[a, b]
    for k in range(6):
        # p_k = p_{k-1} + R_{k-1} t_k ;  R_k = R_{k-1} R_k,placement Rot(q_k)
        for a in range(3):
            pc[a] += Rc[a, 0] * chain_t[k, 0] + Rc[a, 1] * chain_t[k, 1] + Rc[a, 2] * chain_t[k, 2]
        for a in range(3):
            for b in range(3):
                T[a, b] = Rc[a, 0] * chain_R[k, 0, b] + Rc[a, 1] * chain_R[k, 1, b] + Rc[a, 2] * chain_R[k, 2, b]
        _rot(axes[k], q[k], Rr)
        for a in range(3):
            for b in range(3):
                Rc[a, b] = T[a, 0] * Rr[0, b] + T[a, 1] * Rr[1, b] + T[a, 2] * Rr[2, b]
        m = mass[k]
        for a in range(3):
            acc[a] += m * (pc[a] + Rc[a, 0] * lever[k, 0] + Rc[a, 1] * lever[k, 1] + Rc[a, 2] * lever[k, 2])


@nb.njit(**_JIT)
def _numerical_leg(pw, Rw, sole_p, sole_R, ref, KN, q_out, nwork):
    """A numerical leg (kind 1): the sole pose in the waist frame, the tracking iteration of
    ``kinematics/numerical_ik.py`` from ``ref``; returns an IKReason code (0 ok, 1 unreachable)."""
    P = np.empty(3)
    Rt = np.empty((3, 3))
    for i in range(3):
        P[i] = Rw[0, i] * (sole_p[0] - pw[0]) + Rw[1, i] * (sole_p[1] - pw[1]) + Rw[2, i] * (sole_p[2] - pw[2])
        for j in range(3):
            Rt[i, j] = Rw[0, i] * sole_R[0, j] + Rw[1, i] * sole_R[1, j] + Rw[2, i] * sole_R[2, j]
    return 0 if numerical_ik_track(P, Rt, ref, KN, q_out, nwork) else 1


@nb.njit(**_JIT)
def _eval_legs(pw, Rw, sole_p, sole_R, ref, kc_R, kc_t, kc_len, lo, hi, chain_t, chain_R, axes, mass, lever,
               m_up, c_up, m_tot, q_out, com_out, work, scratch, kind, KN, nwork):
    """Both legs' IK for the waist at ``(pw, Rw)`` (rows 0/1 = support/swing of the stacked
    constants) and the whole-body CoM; returns the first failing reason (0 ok). ``kind[leg]``
    0: the hand-derived closed form; 1: the numerical tracking iteration (constants ``KN[leg]``)."""
    for a in range(3):
        com_out[a] = m_up * (pw[a] + Rw[a, 0] * c_up[0] + Rw[a, 1] * c_up[1] + Rw[a, 2] * c_up[2])
    for leg in range(2):
        if kind[leg] == 0:
            reason, _ = leg_ik_pose(pw, Rw, sole_p[leg], sole_R[leg], ref[leg], kc_R[leg, 0], kc_t[leg, 0],
                                    kc_R[leg, 1], kc_t[leg, 1], kc_len[leg, 0], kc_len[leg, 1], lo[leg], hi[leg],
                                    q_out[leg], work)
        else:
            reason = _numerical_leg(pw, Rw, sole_p[leg], sole_R[leg], ref[leg], KN[leg], q_out[leg], nwork)
        if reason != 0:
            return reason
        _leg_mass_moment(pw, Rw, q_out[leg], chain_t[leg], chain_R[leg], axes[leg], mass[leg], lever[leg],
                         com_out, scratch)
    for a in range(3):
        com_out[a] /= m_tot
    return 0


@nb.njit(**_JIT)
def _solve3(J, r, out):
    """``out = J^{-1} r`` (Cramer); returns False if ``J`` is singular."""
    det = (J[0, 0] * (J[1, 1] * J[2, 2] - J[1, 2] * J[2, 1])
           - J[0, 1] * (J[1, 0] * J[2, 2] - J[1, 2] * J[2, 0])
           + J[0, 2] * (J[1, 0] * J[2, 1] - J[1, 1] * J[2, 0]))
    if not abs(det) > 1e-12:
        return False
    for c in range(3):
        M = J.copy()
        for a in range(3):
            M[a, c] = r[a]
        out[c] = (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
                  - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
                  + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])) / det
    return True


@nb.njit(**_JIT)
def legs_newton(pw, Rw, sole_p, sole_R, ref, kc_R, kc_t, kc_len, lo, hi, chain_t, chain_R, axes, mass, lever,
                m_up, c_up, m_tot, com_target, tol, max_iter, h, q_out, J, jstate, kind, KN):
    """Newton on the waist position (module docstring). ``pw`` (3,) start value, updated
    in place; ``q_out`` (2, 6) support / swing leg angles. ``J`` (3, 3) the Jacobian kept
    from the previous call (valid if ``jstate[0] == 1``): it is reused (chord steps) and
    re-evaluated by forward differences only when missing or when a step reduced the
    residual by less than 10x, so a warm-started call usually needs no new Jacobian. Returns ``(status, iterations,
    |p*_CoM - p_CoM|)``; status 0 converged, 1-3 an ``IKReason`` of a leg, 4 not converged,
    5 singular Jacobian."""
    work = np.empty(LEG_WORK_SIZE)
    nwork = np.empty(numerical_work_size(6))
    scratch = np.empty((4, 3, 3))
    com = np.empty(3)
    com_h = np.empty(3)
    q_h = np.empty((2, 6))
    r = np.empty(3)
    dp = np.empty(3)
    p_h = np.empty(3)
    err = np.inf
    prev_err = np.inf
    for it in range(max_iter + 1):
        st = _eval_legs(pw, Rw, sole_p, sole_R, ref, kc_R, kc_t, kc_len, lo, hi, chain_t, chain_R, axes, mass,
                        lever, m_up, c_up, m_tot, q_out, com, work, scratch, kind, KN, nwork)
        if st != 0:
            return st, it, err
        for leg in range(2):     # a numerical leg's next solve starts from this iterate's angles
            if kind[leg] == 1:
                for k in range(6):
                    ref[leg, k] = q_out[leg, k]
        for a in range(3):
            r[a] = com_target[a] - com[a]
        err = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        if err < tol:
            return 0, it, err
        if it == max_iter:
            break
        if jstate[0] != 1 or err > 0.1 * prev_err:
            jstate[0] = 1
            for c in range(3):
                for a in range(3):
                    p_h[a] = pw[a]
                p_h[c] += h
                st = _eval_legs(p_h, Rw, sole_p, sole_R, q_out, kc_R, kc_t, kc_len, lo, hi, chain_t, chain_R,
                                axes, mass, lever, m_up, c_up, m_tot, q_h, com_h, work, scratch, kind, KN,
                                nwork)
                if st != 0:
                    jstate[0] = 0
                    return st, it, err
                for a in range(3):
                    J[a, c] = (com_h[a] - com[a]) / h
        if not _solve3(J, r, dp):
            jstate[0] = 0
            return 5, it, err
        prev_err = err
        for a in range(3):
            pw[a] += dp[a]
    jstate[0] = 0
    return 4, max_iter, err


#: layout of one leg's row of the packed constants (name, size)
_CONST_LAYOUT = (("R0", 9), ("t0", 3), ("Re", 9), ("te", 3), ("len", 2), ("lo", 6), ("hi", 6),
                 ("chain_t", 18), ("chain_R", 54), ("axes", 18), ("mass", 6), ("lever", 18))
_OFF: dict[str, int] = {}
_o = 0
for _name, _size in _CONST_LAYOUT:
    _OFF[_name] = _o
    _o += _size
#: size of one leg's packed constants (offsets hard-coded in solve_legs_packed)
N_CONST = _o
#: packed per-call input: R*_torso (9), support sole p (3), R (9), swing sole p (3), R (9), p*_CoM (3)
N_INPUT = 36


@nb.njit(**_JIT)
def _quat_to_rot(x, y, z, w, R):
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - z * w)
    R[0, 2] = 2.0 * (x * z + y * w)
    R[1, 0] = 2.0 * (x * y + z * w)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - x * w)
    R[2, 0] = 2.0 * (x * z - y * w)
    R[2, 1] = 2.0 * (y * z + x * w)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@nb.njit(**_JIT)
def _rot_to_quat(R, out):
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation matrix (Shepperd's method)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    out[0], out[1], out[2], out[3] = x / n, y / n, z / n, w / n


@nb.njit(**_JIT)
def solve_legs_packed(q, qcols, com_now, inp, C, m_tot, tol, max_iter, h, J, jstate, kind, KN):
    """The whole closed-form lower-body solve on a configuration ``q`` (nq, base = torso
    link; updated in place on success): ``c_up`` from the whole-body CoM ``com_now`` of
    ``q`` minus its legs, then :func:`legs_newton`. ``qcols`` (2, 6) configuration indices
    of the support / swing leg; ``C`` (2, N_CONST) packed constants; ``inp`` (N_INPUT,)
    packed targets; ``J``, ``jstate`` the kept Jacobian (:func:`legs_newton`); ``kind`` (2,),
    ``KN`` (2, k) each leg's solver and numerical constants (:func:`_eval_legs`). Returns
    ``(status, iterations, |p*_CoM - p_CoM|)``."""
    kc_R = np.empty((2, 2, 3, 3))
    kc_t = np.empty((2, 2, 3))
    kc_len = np.empty((2, 2))
    lo = np.empty((2, 6))
    hi = np.empty((2, 6))
    chain_t = np.empty((2, 6, 3))
    chain_R = np.empty((2, 6, 3, 3))
    axes = np.empty((2, 6, 3))
    mass = np.empty((2, 6))
    lever = np.empty((2, 6, 3))
    for g in range(2):
        c = C[g]
        kc_R[g, 0] = c[0:9].reshape((3, 3))
        kc_t[g, 0] = c[9:12]
        kc_R[g, 1] = c[12:21].reshape((3, 3))
        kc_t[g, 1] = c[21:24]
        kc_len[g] = c[24:26]
        lo[g] = c[26:32]
        hi[g] = c[32:38]
        chain_t[g] = c[38:56].reshape((6, 3))
        chain_R[g] = c[56:110].reshape((6, 3, 3))
        axes[g] = c[110:128].reshape((6, 3))
        mass[g] = c[128:134]
        lever[g] = c[134:152].reshape((6, 3))
    Rw = inp[0:9].copy().reshape((3, 3))
    sole_p = np.empty((2, 3))
    sole_R = np.empty((2, 3, 3))
    sole_p[0] = inp[9:12]
    sole_R[0] = inp[12:21].copy().reshape((3, 3))
    sole_p[1] = inp[21:24]
    sole_R[1] = inp[24:33].copy().reshape((3, 3))
    com_target = inp[33:36].copy()
    # upper-body CoM in the torso frame of q: (M p_CoM - sum_legs m_k x_k) / m_up
    Rb = np.empty((3, 3))
    _quat_to_rot(q[3], q[4], q[5], q[6], Rb)
    pb = q[0:3].copy()
    ref = np.empty((2, 6))
    acc = np.zeros(3)
    scratch = np.empty((4, 3, 3))
    for g in range(2):
        for k in range(6):
            ref[g, k] = q[qcols[g, k]]
        _leg_mass_moment(pb, Rb, ref[g], chain_t[g], chain_R[g], axes[g], mass[g], lever[g], acc, scratch)
    m_up = m_tot - (mass[0].sum() + mass[1].sum())
    d = np.empty(3)
    for a in range(3):
        d[a] = (m_tot * com_now[a] - acc[a]) / m_up - pb[a]
    c_loc = np.empty(3)
    for a in range(3):
        c_loc[a] = Rb[0, a] * d[0] + Rb[1, a] * d[1] + Rb[2, a] * d[2]
    q_legs = np.empty((2, 6))
    st, it, err = legs_newton(pb, Rw, sole_p, sole_R, ref, kc_R, kc_t, kc_len, lo, hi, chain_t, chain_R, axes,
                              mass, lever, m_up, c_loc, m_tot, com_target, tol, max_iter, h, q_legs, J, jstate,
                              kind, KN)
    if st == 0:
        for g in range(2):
            for k in range(6):
                q[qcols[g, k]] = q_legs[g, k]
        q[0], q[1], q[2] = pb[0], pb[1], pb[2]
        quat = np.empty(4)
        _rot_to_quat(Rw, quat)
        q[3], q[4], q[5], q[6] = quat[0], quat[1], quat[2], quat[3]
    return st, it, err


class ClosedFormLowerBodyIK:
    """Algorithm 3's problem by closed-form legs + Newton on the waist position, with the
    numerical :class:`LowerBodyIK` as fallback (module docstring). A leg outside the
    hand-derived pattern (``kind`` 1) is solved by the numerical tracking iteration inside the
    same kernel (the name stays: the waist's Newton and the fallback are the same). Same
    interface as ``LowerBodyIK.solve``; on return ``self.data`` holds frames and CoM of the
    result. ``ValueError`` for legs the kernel cannot take (not 6 joints, not hanging from the
    free-flyer body, bodies below the hip beyond the leg's)."""

    def __init__(self, robot: RobotModel, support: str = "right", tol: float = 1e-7, max_iter: int = 20,
                 reference=None) -> None:
        self.reference = LowerBodyIK(robot, support, tol=tol, max_iter=max_iter) if reference is None else reference
        ref = self.reference
        self.robot, self.model, self.tol, self.max_iter = robot, robot.model, tol, max_iter
        self.support = ref.support
        self.data = ref.data          # one pin.Data: callers read frames from it after either path
        m = robot.model
        swing = "left" if ref.support == "right" else "right"
        names = (f"{ref.support}_leg", f"{swing}_leg")
        for name in names:
            if robot.limbs[name].root != robot.base_link:
                raise ValueError(f"{name}: root must be the torso link {robot.base_link!r}")
            if len(robot.limbs[name].joints) != 6:
                raise ValueError(f"{name}: the compiled lower body takes 6-joint legs, got "
                                 f"{len(robot.limbs[name].joints)}")
        bl = m.frames[robot.frame_id(robot.base_link)]
        if bl.parentJoint != 1 or not bl.placement.isIdentity(1e-12):
            raise ValueError(f"compiled legs: {robot.base_link!r} must be the free-flyer body itself")
        jids = [[m.getJointId(j) for j in robot.limbs[n].joints] for n in names]
        for js in jids:     # every body below the hip is one of the six leg joints' bodies
            below = [j for j in range(1, m.njoints) if self._is_descendant(j, js[0])]
            if sorted(below) != sorted(js):
                raise ValueError("compiled legs: a leg subtree has bodies beyond its six joints")
        self.consts = np.zeros((2, N_CONST))
        #: per leg (support, swing): 0 the hand-derived closed form, 1 the numerical tracking iteration
        self.kind = np.zeros(2, np.int64)
        kn: list[np.ndarray] = []
        for g, (name, js) in enumerate(zip(names, jids)):
            try:
                lg = LimbIK(robot, name)
                vals = {"R0": lg.R0, "t0": lg.t0, "Re": lg.Re, "te": lg.te, "len": [lg.l1, lg.l2],
                        "lo": lg.lower, "hi": lg.upper, "chain_t": [t for t, _ in lg._chain],
                        "chain_R": [R for _, R in lg._chain], "axes": [_AXIS[a] for a in lg.axes]}
                kn.append(np.zeros(0))
            except LimbStructureError:
                # no hand-derived closed form (e.g. offsets between the hip or ankle axes): the
                # numerical solver's chain, solved by its tracking iteration from the previous legs
                c = limb_solver(robot, name).chain
                self.kind[g] = 1
                vals = {"lo": c.lower, "hi": c.upper, "chain_t": c.t, "chain_R": c.R, "axes": c.axes}
                kn.append(numerical_leg_constants(c, np.asarray(robot.half_sitting_joints)[
                    list(robot.limbs[name].joint_index)]))
            vals.update({"mass": [m.inertias[j].mass for j in js], "lever": [m.inertias[j].lever for j in js]})
            for key, size in _CONST_LAYOUT:
                if key in vals:
                    self.consts[g, _OFF[key]:_OFF[key] + size] = np.ravel(np.asarray(vals[key], dtype=float))
        self.KN = np.zeros((2, max(1, max(len(k) for k in kn))))
        for g, k in enumerate(kn):
            self.KN[g, :len(k)] = k
        self.m_tot = float(sum(inertia.mass for inertia in m.inertias))
        self.qcols = np.stack([N_BASE_Q + np.array(ref.sup_index), N_BASE_Q + np.array(ref.swing_index)])
        self._inp = np.empty(N_INPUT)
        self._J = np.zeros((3, 3))             # d p_CoM / d p_w kept between calls
        self._jstate = np.zeros(1, np.int64)
        #: calls answered by the numerical reference (closed form failed or not converged)
        self.fallbacks = 0

    def _is_descendant(self, j: int, root: int) -> bool:
        while j > 0:
            if j == root:
                return True
            j = self.model.parents[j]
        return False

    def solve(self, q0: np.ndarray, targets, sole_world: pin.SE3):
        """Algorithm 3's solution from ``q0`` (nq) -> ``LowerBodyResult`` (module docstring)."""
        m, d = self.model, self.data
        q = np.array(q0, dtype=float)
        com_now = pin.centerOfMass(m, d, q, False)
        inp = self._inp
        inp[0:9] = targets.R_torso.ravel()
        inp[9:12] = sole_world.translation
        inp[12:21] = sole_world.rotation.ravel()
        inp[21:24] = targets.p_swing
        inp[24:33] = targets.R_swing.ravel()
        inp[33:36] = targets.p_com
        st, it, err = solve_legs_packed(q, self.qcols, com_now, inp, self.consts, self.m_tot, self.tol,
                                        self.max_iter, FD_STEP_M, self._J, self._jstate, self.kind, self.KN)
        if st != 0:
            self.fallbacks += 1
            return self.reference.solve(q0, targets, sole_world)
        pin.centerOfMass(m, d, q, False)
        pin.updateFramePlacements(m, d)
        return LowerBodyResult(q, True, it, err)


__all__ = ["ClosedFormLowerBodyIK", "legs_newton", "solve_legs_packed", "FD_STEP_M", "N_CONST", "N_INPUT"]
