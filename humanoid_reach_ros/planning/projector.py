"""Algorithm 1 ``ProjectConfig`` of Kanehiro et al. (Sec. III-B), batched in numpy.

The goal configuration space (eq. 1) is ``q_goal = (p_e, rpy_e, z_t, rpy_t)``: hand
pose, trunk height and trunk orientation. The whole robot mass is assumed to be
concentrated at one point ``COG_approx`` fixed to the trunk (``base_link``, the
waist), so the trunk position that keeps ``COG_approx`` above its place is
closed-form, and the four 6-DOF limbs then follow from their closed-form IK
(:mod:`humanoid_reach_ros.kinematics.hand_derived`)::

    R_e = RPY(rpy_e);  R_t = RPY(rpy_t)                      (RPY = Rz Ry Rx)
    p_t = R_t v + COG_approx;  p_t[z] = z_t                  (lines 2-4)
    right arm IK (chest -> hand), else left arm IK             (lines 5-9)
    right leg IK (trunk -> r_sole stance), left leg IK         (lines 10-15)

Our choices, named:

* ``COG_approx`` and ``v``: the exact COG of the reference posture (half-sitting,
  standing on the stance) taken as fixed to the trunk: ``v = R_ref^T (p_trunk_ref -
  COG_ref)`` in the trunk frame, the horizontal ``COG_approx`` = the reference COG's.
* Fixed joints (as in the paper, Fig. 3): chest (CHEST_JOINT0/1), head and grippers at
  their reference values; the arms hang from ``CHEST_LINK1``, whose pose is the trunk
  pose times the constant trunk -> chest transform of the reference posture. The arm
  not used keeps its reference angles.
* Among the closed-form branches within joint limits, the one nearest the reference
  posture is taken (``LimbIK`` default).

Implementation: :meth:`Projector.project_config` (goal sampling) is numpy-batched
over samples (legs through the compiled leg IK of ``LimbIK``); the planner's
:meth:`Projector.project_plan_config` runs as one numba kernel over its rows
(``_project_plan_kernel``: trunk pose, arm joints and limits, both legs by
``limb_ik.leg_ik_pose``), because the planner calls it for every tree node and edge
point in many small batches. A ``Projector`` built on ``LimbIKSet(compiled=False)``
runs the numpy reference path instead (same results; the tests compare them).

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from humanoid_reach_ros.codes import ARM_CODES, ARM_LEFT, ARM_NONE, ARM_RIGHT
from humanoid_reach_ros.planning.wgr import matrix_rpy, rpy_matrix
from humanoid_reach_ros.kinematics import (LEG_WORK_SIZE, LimbIKSet, leg_ik_pose, numerical_ik_pose,
                                           numerical_work_size)
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel

ARMS = ("right_arm", "left_arm")
LEGS = ("right_leg", "left_leg")
#: numba options; nogil=False: see geometry/distance.py (GIL convoy in the reach_planner node)
_JIT = dict(cache=True, nogil=False, fastmath=False)


def quat_xyzw_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) (x, y, z, w) of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    h = 0.5 * np.asarray(rpy, dtype=float)
    cr, sr = np.cos(h[..., 0]), np.sin(h[..., 0])
    cp, sp = np.cos(h[..., 1]), np.sin(h[..., 1])
    cy, sy = np.cos(h[..., 2]), np.sin(h[..., 2])
    return np.stack([sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=-1)


def quat_xyzw_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) (x, y, z, w)."""
    quat = np.asarray(quat, dtype=float)
    x, y, z, w = (quat[..., k] for k in range(4))
    R = np.empty(quat.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


@nb.njit(**_JIT)
def rpy_into(R, roll, pitch, yaw) -> None:
    """``R`` (3, 3) = ``Rz(yaw) Ry(pitch) Rx(roll)`` (compiled;
    :func:`~humanoid_reach_ros.planning.wgr.rpy_matrix`'s)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    R[0, 0] = cy * cp
    R[0, 1] = cy * sp * sr - sy * cr
    R[0, 2] = cy * sp * cr + sy * sr
    R[1, 0] = sy * cp
    R[1, 1] = sy * sp * sr + cy * cr
    R[1, 2] = sy * sp * cr - cy * sr
    R[2, 0] = -sp
    R[2, 1] = cp * sr
    R[2, 2] = cp * cr


@nb.njit(**_JIT)
def _trunk_row(k, q_plan, na, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, Rt, pt, Q, trunk_p, trunk_R):
    """Row ``k`` of the projection kernels, up to the legs: the trunk pose by lines 2-4 into ``Rt``,
    ``pt``, ``trunk_p[k]``, ``trunk_R[k]``; ``Q[k]`` the reference with that base and the row's arm
    joints; whether the arm joints are within their limits."""
    roll, pitch, yaw = q_plan[k, na + 1], q_plan[k, na + 2], q_plan[k, na + 3]
    rpy_into(Rt, roll, pitch, yaw)
    for a in range(3):
        pt[a] = Rt[a, 0] * v[0] + Rt[a, 1] * v[1] + Rt[a, 2] * v[2]
    pt[0] += cog_xy[0]
    pt[1] += cog_xy[1]
    pt[2] = q_plan[k, na]
    for a in range(3):
        trunk_p[k, a] = pt[a]
        for b in range(3):
            trunk_R[k, a, b] = Rt[a, b]
    for i in range(q_ref.shape[0]):
        Q[k, i] = q_ref[i]
    Q[k, 0], Q[k, 1], Q[k, 2] = pt[0], pt[1], pt[2]
    hr, hp, hy = 0.5 * roll, 0.5 * pitch, 0.5 * yaw
    cr, sr = math.cos(hr), math.sin(hr)
    cp, sp = math.cos(hp), math.sin(hp)
    cy, sy = math.cos(hy), math.sin(hy)
    Q[k, 3] = sr * cp * cy - cr * sp * sy
    Q[k, 4] = cr * sp * cy + sr * cp * sy
    Q[k, 5] = cr * cp * sy - sr * sp * cy
    Q[k, 6] = cr * cp * cy + sr * sp * sy
    lim = True
    for a in range(na):
        x = q_plan[k, a]
        Q[k, arm_cols[a]] = x
        if not (x >= arm_lo[a] and x <= arm_hi[a]):
            lim = False
    return lim


@nb.njit(**_JIT)
def _project_plan_kernel(q_plan, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R, leg_ref,
                         R0, t0, Re, te, l1, l2, leg_lo, leg_hi, Q, ok, trunk_p, trunk_R, fails):
    """:meth:`Projector.project_plan_config` for N rows in one compiled call (same
    steps as the numpy path: trunk pose by lines 2-4, arm joints set and limit-checked,
    right then left leg by :func:`~humanoid_reach_ros.kinematics.hand_derived.leg_ik_pose` with the
    limb's default reference). Rows ``(q_arm (na), z_t, rpy_t (3))``, ``na`` the arm's
    joints (``arm_cols``). ``fails``: (right_leg, left_leg, arm_limits) counts."""
    n = q_plan.shape[0]
    na = arm_cols.shape[0]
    Rt = np.empty((3, 3))
    pt = np.empty(3)
    qleg = np.empty(6)
    work = np.empty(LEG_WORK_SIZE)
    for k in range(n):
        ok[k] = False
        if not _trunk_row(k, q_plan, na, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, Rt, pt, Q, trunk_p, trunk_R):
            fails[2] += 1
            continue
        good = True
        for g in range(2):
            reason, _ = leg_ik_pose(pt, Rt, feet_p[g], feet_R[g], leg_ref[g], R0[g], t0[g], Re[g], te[g], l1[g],
                                    l2[g], leg_lo[g], leg_hi[g], qleg, work)
            if reason != 0:
                fails[g] += 1
                good = False
                break
            for a in range(6):
                Q[k, leg_cols[g, a]] = qleg[a]
        ok[k] = good


@nb.njit(**_JIT)
def _project_plan_numerical_kernel(q_plan, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, leg_cols, feet_p, feet_R,
                                   leg_K, seeded, seed_grid, seed_table, leg_default, Q, ok, trunk_p, trunk_R, fails):
    """:meth:`Projector.project_plan_config` for N rows in one compiled call where both legs are
    of the numerical kind (the G1's): the steps of :func:`_project_plan_kernel`, each leg by
    :func:`~humanoid_reach_ros.kinematics.numerical_ik.numerical_ik_pose` from the numpy path's
    start (``Projector._leg_ref``: the trunk grid's nearest leg solution, ``seed_table`` (2, nz,
    np, 6) over ``seed_grid`` = (z0, dz, pitch0, dpitch), when ``seeded``; else ``leg_default``
    (2, 6)). ``leg_K`` (2, k): the legs' packed constants. ``fails``: (right_leg, left_leg,
    arm_limits) counts."""
    n = q_plan.shape[0]
    na = arm_cols.shape[0]
    Rt = np.empty((3, 3))
    pt = np.empty(3)
    P = np.empty(3)
    Rl = np.empty((3, 3))
    qleg = np.empty(6)
    work = np.empty(numerical_work_size(6))
    for k in range(n):
        ok[k] = False
        if not _trunk_row(k, q_plan, na, v, cog_xy, q_ref, arm_cols, arm_lo, arm_hi, Rt, pt, Q, trunk_p, trunk_R):
            fails[2] += 1
            continue
        iz, ip = 0, 0
        if seeded:
            s20 = min(max(Rt[2, 0], -1.0), 1.0)
            tp = -math.asin(s20)
            iz = min(max(int(np.rint((pt[2] - seed_grid[0]) / seed_grid[1])), 0), seed_table.shape[1] - 1)
            ip = min(max(int(np.rint((tp - seed_grid[2]) / seed_grid[3])), 0), seed_table.shape[2] - 1)
        good = True
        for g in range(2):
            fp, fR = feet_p[g], feet_R[g]
            for i in range(3):     # the foot in the trunk frame (GeneralLimb._relative)
                P[i] = Rt[0, i] * (fp[0] - pt[0]) + Rt[1, i] * (fp[1] - pt[1]) + Rt[2, i] * (fp[2] - pt[2])
                for j in range(3):
                    Rl[i, j] = Rt[0, i] * fR[0, j] + Rt[1, i] * fR[1, j] + Rt[2, i] * fR[2, j]
            ref = seed_table[g, iz, ip] if seeded else leg_default[g]
            if not numerical_ik_pose(P, Rl, ref, leg_K[g], qleg, work):
                fails[g] += 1
                good = False
                break
            for a in range(6):
                Q[k, leg_cols[g, a]] = qleg[a]
        ok[k] = good


#: the limbs of ``ProjectionResult.failed``'s columns
FAILURE_LIMBS = ("right_arm", "left_arm", "right_leg", "left_leg")


@dataclass(frozen=True, eq=False)
class ProjectionResult:
    """Outcome of :meth:`Projector.project_config` for N samples.

    ``q`` (N, nq): full configurations (valid only where ``ok``; failed rows keep the
    reference values of the limbs not solved); ``ok`` (N,); ``arm`` (N,) int8: the arm
    code (codes.ARM_RIGHT, ARM_LEFT; ARM_NONE where no arm reached); ``failures``: IK
    failures per limb, counted as in
    Table I (left arm tried only where the right one failed in ``auto`` mode, the
    legs only where an arm succeeded, the left leg only after the right one);
    ``trunk_p`` (N, 3), ``trunk_R`` (N, 3, 3): trunk (waist) poses; ``failed`` (N, 4) bool or
    None: per row, the limbs of ``FAILURE_LIMBS`` whose failure ``failures`` counts (its sum
    over the rows is ``failures``; :meth:`Projector.project_config` only), so that a prefix's
    counts need no second projection.
    """

    q: np.ndarray
    ok: np.ndarray
    arm: np.ndarray
    failures: dict
    trunk_p: np.ndarray
    trunk_R: np.ndarray
    failed: np.ndarray | None = None

    def failures_upto(self, end: int) -> dict:
        """``failures`` over the rows before ``end`` (``failed`` needed)."""
        counts = self.failed[:end].sum(axis=0)
        return {k: int(c) for k, c in zip(FAILURE_LIMBS, counts)}


class Projector:
    """Algorithm 1 for a :class:`RobotModel` (see the module docstring).

    ``reference_joints`` (30,): the reference posture (default half-sitting): it fixes
    ``COG_approx``/``v``, the chest transform and the values of every joint that
    Algorithm 1 does not set.
    """

    def __init__(self, robot: RobotModel, ik: LimbIKSet | None = None,
                 reference_joints: np.ndarray | None = None) -> None:
        self.robot = robot
        self.ik = LimbIKSet(robot) if ik is None else ik
        joints = robot.half_sitting_joints if reference_joints is None else np.asarray(reference_joints, float)
        self.q_ref = robot.config(joints, robot.base_on_feet(joints))
        self.cog_ref = robot.com(self.q_ref)
        trunk = robot.frame_pose(self.q_ref, robot.base_link)
        chest = robot.frame_pose(self.q_ref, robot.limbs["right_arm"].root)
        if robot.limbs["left_arm"].root != robot.limbs["right_arm"].root:
            raise ValueError("Projector: both arms must hang from the same link")
        for leg in LEGS:
            if robot.limbs[leg].root != robot.base_link:
                raise ValueError(f"Projector: {leg} must hang from the trunk {robot.base_link!r}")
        #: v: from COG_approx to the trunk origin, in the trunk frame
        self.v = trunk.rotation.T @ (trunk.translation - self.cog_ref)
        #: horizontal position of COG_approx in the world (fixed)
        self.cog_approx_xy = self.cog_ref[:2].copy()
        tc = trunk.inverse() * chest
        self.chest_R_in_trunk = tc.rotation.copy()
        self.chest_p_in_trunk = tc.translation.copy()
        soles = robot.stance_soles
        self.feet = {leg: (s.translation.copy(), s.rotation.copy()) for leg, s in zip(LEGS, soles)}
        self.cols = {name: np.array(spec.joint_index) + N_BASE_Q for name, spec in robot.limbs.items()}
        self._v_c = np.array(self.v, dtype=float)
        self._cog_xy_c = np.array(self.cog_approx_xy, dtype=float)
        self._q_ref_c = np.array(self.q_ref, dtype=float)
        #: project_plan_config runs the fused numba kernel when the IK set is compiled and both
        #: legs have the hand-derived compiled leg kernel (``LimbIK``'s z x y | y | y x pattern);
        #: two numerical legs their own compiled kernel (below); other legs (a general closed
        #: form) go through the limb protocol
        legs = [self.ik[leg] for leg in LEGS]
        self.compiled = bool(getattr(self.ik, "compiled", False)) and all(hasattr(lk, "_kc") for lk in legs)
        self._kernel_legs: tuple = ()
        self._leg_seeds = None   # set_leg_seeds
        #: both legs numerical (6 joints): project_plan_config's compiled kernel for them
        #: (_project_plan_numerical_kernel; the same answers as the limb protocol's path)
        self._numerical_legs = None
        if not self.compiled and all(getattr(lk, "kind", "") == "numerical" and getattr(lk, "n_joints", 0) == 6
                                     and hasattr(getattr(lk, "ik", None), "K") for lk in legs):
            self._numerical_legs = (
                np.ascontiguousarray(np.stack([self.cols[leg] for leg in LEGS]), dtype=np.int64),
                np.ascontiguousarray(np.stack([self.feet[leg][0] for leg in LEGS])),
                np.ascontiguousarray(np.stack([self.feet[leg][1] for leg in LEGS])),
                np.ascontiguousarray(np.stack([lk.ik.K for lk in legs])),
                np.ascontiguousarray(np.stack([lk.ik.q_default for lk in legs])))
        if self.compiled:
            kc = [np.ascontiguousarray(np.stack([lk._kc[i] for lk in legs])) for i in range(8)]
            self._kernel_legs = (
                np.ascontiguousarray(np.stack([self.cols[leg] for leg in LEGS]), dtype=np.int64),
                np.ascontiguousarray(np.stack([self.feet[leg][0] for leg in LEGS])),
                np.ascontiguousarray(np.stack([self.feet[leg][1] for leg in LEGS])),
                np.ascontiguousarray(np.stack([lk.q_default for lk in legs])),
                *kc)
        #: joints of each arm: the planning space of an arm is (q_arm (n), z_t, rpy_t (3))
        self.arm_dof = {arm: len(robot.limbs[f"{arm}_arm"].joints) for arm in ARM_CODES}
        self._kernel_arm = {}
        for arm in ARM_CODES:
            ji = np.array(robot.limbs[f"{arm}_arm"].joint_index)
            self._kernel_arm[arm] = (np.ascontiguousarray(self.cols[f"{arm}_arm"], dtype=np.int64),
                                     np.array(robot.lower[ji], dtype=float), np.array(robot.upper[ji], dtype=float))

    # ------------------------------------------------------------ pieces
    def plan_dim(self, arm: str) -> int:
        """Columns of ``arm``'s planning space: its joints (6; 7 for a redundant arm) + 4."""
        return self.arm_dof[arm] + 4

    def trunk_pose(self, z_t: np.ndarray, rpy_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lines 2-4: ``R_t = RPY(rpy_t)``, ``p_t = R_t v + COG_approx``, ``p_t[z] = z_t``."""
        rpy_t = np.atleast_2d(np.asarray(rpy_t, float))
        z_t = np.broadcast_to(np.asarray(z_t, float), (len(rpy_t),))
        R_t = rpy_matrix(rpy_t)
        p_t = R_t @ self.v
        p_t[:, :2] += self.cog_approx_xy
        p_t[:, 2] = z_t
        return p_t, R_t

    def chest_pose(self, p_t: np.ndarray, R_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose of the arms' root link from trunk poses (fixed chest joints)."""
        return p_t + R_t @ self.chest_p_in_trunk, R_t @ self.chest_R_in_trunk

    def cog_approx(self, q: np.ndarray) -> np.ndarray:
        """World ``COG_approx`` (..., 3) of configurations (..., nq): ``p_t - R_t v``."""
        q = np.asarray(q, float)
        R = quat_xyzw_matrix(q[..., 3:7])
        return q[..., :3] - R @ self.v

    def _base(self, p_t, R_t, rpy_t) -> np.ndarray:
        Q = np.repeat(self.q_ref[None], len(p_t), axis=0)
        Q[:, :3] = p_t
        Q[:, 3:7] = quat_xyzw_from_rpy(rpy_t)
        return Q

    def set_leg_seeds(self, z: np.ndarray, pitch: np.ndarray, Q: np.ndarray) -> None:
        """Starts of a numerical leg's IK (a local solver: its start decides its cost, 265 us a
        G1 leg from ``q_default``): the configurations ``Q`` (nz, np, nq) solved at the trunk
        heights ``z`` (nz,) x pitches ``pitch`` (np,) of a regular grid (``TrunkRegion``'s; rows
        that failed hold NaN); each solve starts from the nearest grid point's legs (or the
        default where that one failed). Closed-form legs ignore it (their reference would pick
        the branch)."""
        z, pitch = np.asarray(z, float), np.asarray(pitch, float)
        dz = float(z[1] - z[0]) if len(z) > 1 else 1.0
        dp = float(pitch[1] - pitch[0]) if len(pitch) > 1 else 1.0
        table = {}
        for leg in LEGS:
            if getattr(self.ik[leg], "kind", "") != "numerical":
                continue
            t = np.array(Q[..., self.cols[leg]], float)
            bad = ~np.all(np.isfinite(t), axis=-1)
            t[bad] = self.ik[leg].q_default
            table[leg] = t
        self._leg_seeds = (float(z[0]), dz, float(pitch[0]), dp, table) if table else None
        if self._leg_seeds is not None and all(leg in table for leg in LEGS):    # the compiled kernel's form
            self._leg_seeds += (np.ascontiguousarray(np.stack([table[leg] for leg in LEGS]), dtype=np.float64),)

    def _leg_ref(self, leg: str, p_t: np.ndarray, R_t: np.ndarray) -> np.ndarray | None:
        seeds = self._leg_seeds
        if seeds is None or leg not in seeds[4]:
            return None
        z0, dz, p0, dp, table = seeds[:5]
        pitch = -np.arcsin(np.clip(R_t[:, 2, 0], -1.0, 1.0))        # R = Rz Ry Rx: R[2, 0] = -sin(pitch)
        iz = np.clip(np.rint((p_t[:, 2] - z0) / dz).astype(np.int64), 0, table[leg].shape[0] - 1)
        ip = np.clip(np.rint((pitch - p0) / dp).astype(np.int64), 0, table[leg].shape[1] - 1)
        return table[leg][iz, ip]

    def _legs(self, Q, p_t, R_t, idx, failures, failed=None) -> np.ndarray:
        """Lines 10-15 on rows ``idx``; returns the rows where both legs succeeded (``failed``:
        ProjectionResult's, marked)."""
        for leg in LEGS:
            if idx.size == 0:
                break
            fp, fR = self.feet[leg]
            res = self.ik.solve(leg, p_t[idx], R_t[idx], fp, fR, self._leg_ref(leg, p_t[idx], R_t[idx]))
            failures[leg] += int(np.count_nonzero(~res.ok))
            if failed is not None:
                failed[idx[~res.ok], FAILURE_LIMBS.index(leg)] = True
            good = idx[res.ok]
            Q[good[:, None], self.cols[leg][None]] = res.q[res.ok]
            idx = good
        return idx

    # ------------------------------------------------------------ Algorithm 1
    def project_config(self, p_e, R_e, z_t, rpy_t, arm: str = "auto") -> ProjectionResult:
        """Algorithm 1 for N samples: hand poses ``p_e`` (N, 3), ``R_e`` (N, 3, 3)
        (``RPY(rpy_e)``, see :func:`~humanoid_reach_ros.planning.wgr.rpy_matrix`),
        trunk heights ``z_t`` (N,) and orientations ``rpy_t`` (N, 3).

        ``arm``: ``"auto"`` (right arm, else left: lines 5-9), ``"right"`` or ``"left"``.
        """
        if arm not in ("auto", "right", "left"):
            raise ValueError(f"arm must be 'auto', 'right' or 'left', got {arm!r}")
        p_e = np.atleast_2d(np.asarray(p_e, float))
        R_e = np.asarray(R_e, float).reshape(-1, 3, 3)
        rpy_t = np.atleast_2d(np.asarray(rpy_t, float))
        n = len(rpy_t)
        p_t, R_t = self.trunk_pose(z_t, rpy_t)
        c_p, c_R = self.chest_pose(p_t, R_t)
        Q = self._base(p_t, R_t, rpy_t)
        failures = {"right_arm": 0, "left_arm": 0, "right_leg": 0, "left_leg": 0}
        failed = np.zeros((n, len(FAILURE_LIMBS)), bool)
        arm_used = np.full(n, ARM_NONE, np.int8)
        todo = np.arange(n)
        order = ARMS if arm == "auto" else (("right_arm",) if arm == "right" else ("left_arm",))
        for name in order:
            if todo.size == 0:
                break
            pe = p_e[todo] if len(p_e) > 1 else p_e
            Re = R_e[todo] if len(R_e) > 1 else R_e
            # most samples put the hand out of the arm's reach: solve only the rows that may
            # be reachable (a conservative test; the others fail in the full solve too)
            cand = np.flatnonzero(self.ik[name].maybe_reachable(c_p[todo], c_R[todo], pe, Re))
            ok_rows = np.zeros(len(todo), bool)
            if cand.size:
                res = self.ik.solve(name, c_p[todo[cand]], c_R[todo[cand]], pe[cand] if len(pe) > 1 else pe,
                                    Re[cand] if len(Re) > 1 else Re)
                ok_rows[cand[res.ok]] = True
                good = todo[cand[res.ok]]
                Q[good[:, None], self.cols[name][None]] = res.q[res.ok]
                arm_used[good] = ARM_RIGHT if name == "right_arm" else ARM_LEFT
            failures[name] += int(np.count_nonzero(~ok_rows))
            failed[todo[~ok_rows], FAILURE_LIMBS.index(name)] = True
            todo = todo[~ok_rows]
        idx = self._legs(Q, p_t, R_t, np.flatnonzero(arm_used != ARM_NONE), failures, failed)
        ok = np.zeros(n, bool)
        ok[idx] = True
        arm_used[~ok] = ARM_NONE
        return ProjectionResult(Q, ok, arm_used, failures, p_t, R_t, failed)

    def project_plan_config(self, q_plan, arm: str) -> ProjectionResult:
        """The planner's space (eq. 2): ``q_plan`` (N, n + 4) = (q_arm (n), z_t, rpy_t (3))
        -> full configurations (``n`` the arm's joints: 6, or 7 for a redundant arm, every
        one a planning variable). The reaching arm's joints are set directly, the trunk
        horizontal position by lines 3-4 of Algorithm 1, the legs by closed-form IK;
        everything else at the reference. ``ok``: legs solved and the arm joints within
        their limits. ``failures`` counts leg IK failures (and ``"arm_limits"``)."""
        if arm not in ARM_CODES:
            raise ValueError(f"arm must be 'right' or 'left', got {arm!r}")
        q_plan = np.atleast_2d(np.asarray(q_plan, float))
        na = self.arm_dof[arm]
        if q_plan.shape[1] != na + 4:
            raise ValueError(f"q_plan must have {na + 4} columns (q_arm ({na}), z_t, rpy_t), got {q_plan.shape}")
        if self.compiled:
            return self._project_plan_compiled(q_plan, arm)
        if self._numerical_legs is not None:
            return self._project_plan_numerical(q_plan, arm)
        name = f"{arm}_arm"
        p_t, R_t = self.trunk_pose(q_plan[:, na], q_plan[:, na + 1:na + 4])
        Q = self._base(p_t, R_t, q_plan[:, na + 1:na + 4])
        Q[:, self.cols[name]] = q_plan[:, :na]
        ji = np.array(self.robot.limbs[name].joint_index)
        lim = np.all((q_plan[:, :na] >= self.robot.lower[ji]) & (q_plan[:, :na] <= self.robot.upper[ji]), axis=1)
        failures = {"right_leg": 0, "left_leg": 0, "arm_limits": int(np.count_nonzero(~lim))}
        idx = self._legs(Q, p_t, R_t, np.flatnonzero(lim), failures)
        ok = np.zeros(len(q_plan), bool)
        ok[idx] = True
        arm_used = np.where(ok, ARM_CODES[arm], ARM_NONE).astype(np.int8)
        return ProjectionResult(Q, ok, arm_used, failures, p_t, R_t)

    def _kernel_args(self, arm: str) -> tuple:
        """The constant arguments of ``_project_plan_kernel`` for ``arm`` (after ``q_plan``)."""
        return (self._v_c, self._cog_xy_c, self._q_ref_c, *self._kernel_arm[arm], *self._kernel_legs)

    def _project_plan_compiled(self, q_plan: np.ndarray, arm: str) -> ProjectionResult:
        n = len(q_plan)
        Q = np.empty((n, len(self.q_ref)))
        ok = np.empty(n, np.bool_)
        p_t = np.empty((n, 3))
        R_t = np.empty((n, 3, 3))
        fails = np.zeros(3, np.int64)
        _project_plan_kernel(np.ascontiguousarray(q_plan, dtype=np.float64), self._v_c, self._cog_xy_c,
                             self._q_ref_c, *self._kernel_arm[arm], *self._kernel_legs, Q, ok, p_t, R_t, fails)
        failures = {"right_leg": int(fails[0]), "left_leg": int(fails[1]), "arm_limits": int(fails[2])}
        arm_used = np.where(ok, ARM_CODES[arm], ARM_NONE).astype(np.int8)
        return ProjectionResult(Q, ok, arm_used, failures, p_t, R_t)

    def _project_plan_numerical(self, q_plan: np.ndarray, arm: str) -> ProjectionResult:
        cols, feet_p, feet_R, leg_K, leg_default = self._numerical_legs
        seeds = self._leg_seeds
        if seeds is not None and all(leg in seeds[4] for leg in LEGS):
            grid = np.array(seeds[:4], dtype=float)
            table = seeds[5] if len(seeds) > 5 else np.ascontiguousarray(np.stack([seeds[4][leg] for leg in LEGS]))
            seeded = True
        else:
            grid, table, seeded = np.zeros(4), np.zeros((2, 1, 1, 6)), False
        n = len(q_plan)
        Q = np.empty((n, len(self.q_ref)))
        ok = np.empty(n, np.bool_)
        p_t = np.empty((n, 3))
        R_t = np.empty((n, 3, 3))
        fails = np.zeros(3, np.int64)
        _project_plan_numerical_kernel(np.ascontiguousarray(q_plan, dtype=np.float64), self._v_c, self._cog_xy_c,
                                       self._q_ref_c, *self._kernel_arm[arm], cols, feet_p, feet_R, leg_K, seeded,
                                       grid, table, leg_default, Q, ok, p_t, R_t, fails)
        failures = {"right_leg": int(fails[0]), "left_leg": int(fails[1]), "arm_limits": int(fails[2])}
        arm_used = np.where(ok, ARM_CODES[arm], ARM_NONE).astype(np.int8)
        return ProjectionResult(Q, ok, arm_used, failures, p_t, R_t)

    def plan_config_of(self, q: np.ndarray, arm: str) -> np.ndarray:
        """Inverse of :meth:`project_plan_config` on its image: (N, nq) -> (N, n + 4)."""
        q = np.atleast_2d(np.asarray(q, float))
        R = quat_xyzw_matrix(q[:, 3:7])
        return np.concatenate([q[:, self.cols[f"{arm}_arm"]], q[:, 2:3], matrix_rpy(R)], axis=1)


__all__ = ["Projector", "ProjectionResult", "FAILURE_LIMBS", "quat_xyzw_from_rpy", "quat_xyzw_matrix"]
