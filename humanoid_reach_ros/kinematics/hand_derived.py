"""Closed-form, numpy-batched inverse (and forward) kinematics of the 6-DOF limbs.

Each limb of the HRP-2-class model (``config/robots/hrp2/hrp2.urdf``) is a 6R chain with
three intersecting axes at one end and two intersecting axes at the other, which
makes its IK solvable in closed form (Pieper). Every number used here -- joint
placements, link lengths, tip offsets, joint limits -- is read from the pinocchio
model at construction, and the construction checks that the chain has the assumed
structure (see :func:`LimbIK.__post_init__`); editing ``tools/gen_hrp2_urdf.py``
therefore keeps the IK right, or fails loudly.

Notation (all poses in the world frame, numpy, batched over ``N``):

* ``Rx, Ry, Rz``: elementary rotations; ``q0..q5`` the limb's joints in chain order.
* root pose ``(p_r, R_r)``: the limb's root link (waist ``base_link`` for legs,
  ``CHEST_LINK1`` for arms); ``(t_0, R_0)``: placement of joint 0 in the root frame,
  so the first joint centre is ``c = p_r + R_r t_0`` and its zero frame ``R_c = R_r R_0``.
* tip pose ``(p_t, R_t)``: the sole / hand end-effector frame; ``(t_e, R_e)``: its
  placement in the last joint's frame, so that the last link's pose is
  ``R_5 = R_t R_e^T`` and its origin (the ankle / wrist centre) ``w = p_t - R_5 t_e``.
* ``r = R_5^T (c - w)``: the vector from the ankle/wrist centre to the hip/shoulder
  centre, expressed in the last link's frame. Both solvers start from it.

Legs (``Rz Rx Ry | Ry | Ry Rx``, thigh ``(0,0,-A)``, shank ``(0,0,-B)``)::

    R_5 = R_c Rz(q0) Rx(q1) Ry(q2 + q3 + q4) Rx(q5)
    r   = Rx(-q5) Ry(-q4) [(-A sin q3, 0, A cos q3 + B)]
    cos q3 = (|r|^2 - A^2 - B^2) / (2AB)                 knee, 2 branches (+-)
    q5     = atan2(r_y, r_z)  (or + pi)                   ankle roll, 2 branches
    v      = Rx(q5) r = (r_x, 0, v_z)
    q4     = atan2(-A sin q3, A cos q3 + B) - atan2(r_x, v_z)     ankle pitch
    Rz(q0) Rx(q1) Ry(q2) = R_c^T R_5 Rx(-q5) Ry(-(q3 + q4))   hip, 2 branches:
        q0 = atan2(-M01, M11) (or + pi);  N = Rz(-q0) M = Rx(q1) Ry(q2);
        q2 = atan2(N02, N00);  q1 = atan2(N21, N11)

Arms (``Ry Rx Rz | Ry | Rz Ry``, upper arm ``(0,0,-U)``, forearm ``(0,0,-F)``)::

    R_5 = R_c Ry(q0) Rx(q1) Rz(q2) Ry(q3) Rz(q4) Ry(q5)
    r   = Ry(-q5) Rz(-q4) [(-U sin q3, 0, U cos q3 + F)]
    forearm direction f = Ry(-q5) e_z must satisfy |r - F f| = U:
        r.f = r_z cos q5 - r_x sin q5 = k := (|r|^2 + F^2 - U^2) / (2F)   (= U cos q3 + F)
        rho = hypot(r_x, r_z), phi = atan2(r_x, r_z):
        q5 = -phi +- acos(k / rho)                        wrist pitch, 2 branches
        (real iff |k| <= rho; this single condition is the reachability test: it
        covers |r| > U + F as well as orientations whose wrist-pitch axis cannot
        carry the wrist-yaw axis through the shoulder)
    t = Ry(q5) r - (0, 0, F) = Rz(-q4) Ry(-q3) (0, 0, U) = (-U s3 c4, U s3 s4, U c3):
        q3 = +-atan2(hypot(t_x, t_y), t_z)                elbow, 2 branches
        q4 = atan2(t_y, -t_x)  (+ pi for the negative elbow branch)       wrist yaw
    Ry(q0) Rx(q1) Rz(q2) = R_c^T R_5 Ry(-q5) Rz(-q4) Ry(-q3)  shoulder, 2 branches:
        q0 = atan2(M02, M22) (or + pi);  N = Ry(-q0) M = Rx(q1) Rz(q2);
        q2 = atan2(-N01, N00);  q1 = atan2(-N12, N22)

That is 2 x 2 x 2 = 8 candidate solutions per pose (the general maximum for this
class of 6R chain). Each angle is wrapped into ``[lower, lower + 2 pi)``; the
candidates inside the joint limits (with ``LIMIT_TOL`` slack, then clipped onto the
limits) are kept and the one closest (Euclidean, in joint space) to ``q_ref`` is
returned. Without ``q_ref`` the reference is the limb's half-sitting posture
(``RobotModel.half_sitting_joints``): knee forward, elbow back, the natural branch.

Numerical robustness (errors quoted are bounds on FK(IK(x)) - x):

* Every angle is computed from the quantities the previous ones leave, so the
  solution is self-consistent even where an angle is ill-conditioned: Euler angles
  are peeled off sequentially (first angle by atan2, the other two from
  ``R(-first) M``); the arm's elbow and wrist yaw both come from ``t``, i.e. from the
  wrist pitch actually chosen. Random in-limit poses come back to ~1e-15 (legs) /
  ~1e-13 (arms, see PSI_SNAP).
* The wrist-pitch acos is sqrt-conditioned on its tangent (arm stretched, or wrist
  yaw +-90 deg); |k| within ``PSI_SNAP`` m of rho is snapped onto the tangent
  (cost <= F/U * PSI_SNAP).
* Exact singularities leave one angle free; it is then chosen, within the joint
  limits, closest to ``q_ref``: gimbal lock of the hip / shoulder (|cos q1| <
  ``GIMBAL_TOL``; roll snapped to +-90 deg, cost <= GIMBAL_TOL; only q0 + -sin(q1) q2
  is fixed -- reachable for the right shoulder at -90 deg, arm out sideways, and the
  left at +90 deg); stretched arm (lever U|sin q3| < ``STRETCH_TOL`` m; elbow snapped
  to 0, wrist yaw and shoulder yaw coaxial, only q2 + q4 fixed); hip on the
  ankle-roll axis (< ``SINGULAR_TOL`` m; ankle roll from ``q_ref``). The stretched
  knee is not a singularity of the angle computation (all knee-side angles remain
  unique).
* ``acos``-type arguments are clipped only within ``REACH_TOL`` of +-1: a pose a
  hair beyond the reach (more than ~1e-10 relative, i.e. ~5e-11 m) is reported
  unreachable, never silently projected onto the workspace boundary.
* Limitation: within ~1e-5 rad of a singularity an angle may be determined by the
  data only to ~1e-4 rad (intrinsic conditioning; the returned solution is still
  exact in FK). If the sampled pose is also within that distance of a joint limit,
  the solver can then answer JOINT_LIMITS for a pose that is (barely) feasible.

Failed rows carry ``NaN`` joints, ``ok = False`` and a reason code (:class:`IKReason`).
Implementations: the LEGS are solved by a numba kernel (:func:`_leg_ik_kernel`, one
pose at a time, no temporaries; the planner projects every tree node and edge point
through both legs in many small batches, where numpy's per-call overhead dominated).
The numpy batch code (and, for N = 1, its pure-Python twin) is the reference: same
algorithm, branch order, tolerances and tie-breaking; the arms use it, and
``LimbIK(..., compiled=False)`` / :meth:`LimbIK.solve_reference` use it for the legs
too (tests check kernel == reference to 1e-12). The kernel is compiled into numba's
on-disk cache by :func:`warm_up` (called from ``humanoid_reach_ros.warmup`` through
``ReachPlanner.warm_up``). This module never imports rclpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.kinematics.ik_types import IKReason, IKResult
from humanoid_reach_ros.robot.model import RobotModel

TWO_PI = 2.0 * np.pi

#: slack on acos-type arguments (|cos| <= 1 + REACH_TOL is reachable, then clipped)
REACH_TOL = 1e-10
#: slack on joint limits [rad]; accepted solutions are clipped onto the limits
LIMIT_TOL = 1e-10
#: hip on the ankle-roll axis below this distance [m]: ankle roll taken from q_ref
SINGULAR_TOL = 1e-12
#: gimbal lock of the hip / shoulder Euler angles when |cos(roll)| < GIMBAL_TOL
GIMBAL_TOL = 1e-10
#: extra slack of :meth:`LimbIK.maybe_reachable` (a prefilter must never reject a reachable pose)
REACH_SLACK = 1e-9
#: wrist-pitch tangent snap [m]: |k| within this of rho is treated as tangent
PSI_SNAP = 1e-13
#: arm treated as exactly stretched (q3 := 0, wrist yaw free) below this lever [m]
STRETCH_TOL = 1e-11
#: tolerance of the structural checks on the model (placements, axes)
STRUCT_TOL = 1e-12
#: rotation inputs further than this from orthonormal are rejected (INVALID_INPUT)
ROTATION_TOL = 1e-6
#: numba options of the compiled leg IK; nogil=False: see geometry/distance.py (GIL convoy
#: in the multithreaded reach_planner node)
_JIT = dict(cache=True, nogil=False, fastmath=False)
#: size of the float scratch array of :func:`leg_ik_pose`
LEG_WORK_SIZE = 110

_AXIS_OF_JOINT = {"JointModelRX": "x", "JointModelRY": "y", "JointModelRZ": "z"}
#: joint-axis pattern (chain order) -> solver kind
_KINDS = {"zxyyyx": "leg", "yxzyzy": "arm"}


class LimbStructureError(ValueError):
    """The pinocchio model does not have the structure the closed form assumes."""


# ----------------------------------------------------------------- helpers
_PLANE = {"x": (1, 2, 0), "y": (2, 0, 1), "z": (0, 1, 2)}


def _rot(axis: str, theta: np.ndarray) -> np.ndarray:
    """Elementary rotation matrices, shape theta.shape + (3, 3)."""
    i, j, k = _PLANE[axis]
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros(np.shape(theta) + (3, 3))
    out[..., k, k] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _as_batch(a, tail: tuple[int, ...], name: str) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.shape == tail:
        return a[None]
    if a.ndim != len(tail) + 1 or a.shape[1:] != tail:
        raise ValueError(f"{name}: expected shape {tail} or (N, {', '.join(map(str, tail))}), got {a.shape}")
    return a


def _valid_rotation(R: np.ndarray) -> np.ndarray:
    """Finite, orthonormal within ROTATION_TOL and right-handed (det > 0)."""
    with np.errstate(invalid="ignore", over="ignore"):
        err = np.abs(np.einsum("nki,nkj->nij", R, R) - np.eye(3)).max(axis=(-2, -1))
        det = np.einsum("ni,ni->n", np.cross(R[:, 0], R[:, 1]), R[:, 2])
    return (err <= ROTATION_TOL) & (det > 0.0)   # NaN compares False


# ----------------------------------------------------------------- the solver
@dataclass(frozen=True, eq=False)
class LimbIK:
    """Closed-form IK / FK of one 6-DOF limb of ``model`` (``model.limbs[limb_name]``).

    Construction reads the kinematics from the pinocchio model and raises
    :class:`LimbStructureError` unless: the six limb joints are single-axis revolute
    joints (RX/RY/RZ) forming a serial chain from the root link to the tip frame,
    with axis pattern ``z x y y y x`` (leg) or ``y x z y z y`` (arm); joints 1..5 have
    identity placement rotations; joints 1, 2 and 5 have zero placement translation
    (the first three axes and the last two intersect); joints 3 and 4 are offset
    purely along the parent's z axis (no lateral offsets). The placement of joint 0
    in the root link and of the tip frame in the last link are arbitrary.
    """

    model: RobotModel
    limb_name: str
    compiled: bool = True
    kind: str = field(init=False)
    joint_names: tuple[str, ...] = field(init=False)
    axes: str = field(init=False)
    lower: np.ndarray = field(init=False, repr=False)
    upper: np.ndarray = field(init=False, repr=False)
    q_default: np.ndarray = field(init=False, repr=False)
    l1: float = field(init=False)   # thigh / upper arm: joint 2 -> joint 3 along -z
    l2: float = field(init=False)   # shank / forearm:   joint 3 -> joint 4 along -z
    t0: np.ndarray = field(init=False, repr=False)   # joint 0 in the root link
    R0: np.ndarray = field(init=False, repr=False)
    te: np.ndarray = field(init=False, repr=False)   # tip frame in the last link
    Re: np.ndarray = field(init=False, repr=False)
    _chain: tuple = field(init=False, repr=False)    # (t_i, R_i) joint placements
    _py: tuple = field(init=False, repr=False)       # R0, t0, Re, te as Python lists
    _lo: list = field(init=False, repr=False)
    _kc: tuple = field(init=False, repr=False)       # constants of the compiled kernel
    _hi: list = field(init=False, repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        m = self.model.model
        if self.limb_name not in self.model.limbs:
            raise KeyError(f"unknown limb {self.limb_name!r}; have {sorted(self.model.limbs)}")
        spec = self.model.limbs[self.limb_name]
        if len(spec.joints) != 6:
            raise LimbStructureError(f"{self.limb_name}: closed-form IK needs 6 joints, got {len(spec.joints)}")

        def bad(msg: str) -> LimbStructureError:
            return LimbStructureError(f"{self.limb_name}: {msg} (closed-form limb IK assumptions violated)")

        jids = [m.getJointId(n) for n in spec.joints]
        axes = ""
        for n, jid in zip(spec.joints, jids):
            if jid >= m.njoints:
                raise bad(f"joint {n!r} not in the model")
            short = m.joints[jid].shortname()
            if short not in _AXIS_OF_JOINT:
                raise bad(f"joint {n!r} is {short}, expected a revolute joint about +x, +y or +z")
            axes += _AXIS_OF_JOINT[short]
        if axes not in _KINDS:
            raise bad(f"axis pattern {axes!r} is neither leg 'zxyyyx' nor arm 'yxzyzy'")
        for k in range(1, 6):
            if m.parents[jids[k]] != jids[k - 1]:
                raise bad(f"{spec.joints[k]} is not the child of {spec.joints[k - 1]}")
        root_f = m.frames[self.model.frame_id(spec.root)]
        if root_f.parentJoint != m.parents[jids[0]]:
            raise bad(f"root link {spec.root!r} is not the parent of {spec.joints[0]}")
        tip_f = m.frames[self.model.frame_id(spec.tip)]
        if tip_f.parentJoint != jids[5]:
            raise bad(f"tip frame {spec.tip!r} is not attached to {spec.joints[5]}")

        P = [m.jointPlacements[j] for j in jids]
        for k in range(1, 6):
            if np.abs(P[k].rotation - np.eye(3)).max() > STRUCT_TOL:
                raise bad(f"{spec.joints[k]} placement is rotated; link frames must stay parallel")
        for k in (1, 2, 5):
            if np.abs(P[k].translation).max() > STRUCT_TOL:
                raise bad(f"{spec.joints[k]} is offset by {P[k].translation}; its axis must intersect the previous one")
        for k in (3, 4):
            t = P[k].translation
            if np.abs(t[:2]).max() > STRUCT_TOL or t[2] >= -STRUCT_TOL:
                raise bad(f"{spec.joints[k]} offset {t} must be purely along -z (no lateral offset)")

        root_to_j0 = root_f.placement.inverse() * P[0]
        lo = np.array([m.lowerPositionLimit[m.joints[j].idx_q] for j in jids])
        hi = np.array([m.upperPositionLimit[m.joints[j].idx_q] for j in jids])
        if np.any(hi < lo):
            raise bad("a joint has upper < lower limit")
        set_(self, "kind", _KINDS[axes])
        set_(self, "joint_names", tuple(spec.joints))
        set_(self, "axes", axes)
        set_(self, "lower", lo)
        set_(self, "upper", hi)
        q_hs = np.asarray(self.model.half_sitting_joints)[list(spec.joint_index)]
        set_(self, "q_default", np.clip(q_hs, lo, hi))
        set_(self, "l1", float(-P[3].translation[2]))
        set_(self, "l2", float(-P[4].translation[2]))
        set_(self, "t0", np.array(root_to_j0.translation))
        set_(self, "R0", np.array(root_to_j0.rotation))
        set_(self, "te", np.array(tip_f.placement.translation))
        set_(self, "Re", np.array(tip_f.placement.rotation))
        chain = [(self.t0, self.R0)] + [(np.array(p.translation), np.array(p.rotation)) for p in P[1:]]
        set_(self, "_chain", tuple(chain))
        set_(self, "_py", (self.R0.tolist(), self.t0.tolist(), self.Re.tolist(), self.te.tolist()))
        set_(self, "_kc", (self.R0.copy(), self.t0.copy(), self.Re.copy(), self.te.copy(), self.l1, self.l2,
                           lo.copy(), hi.copy()))   # writable C arrays: one numba signature
        set_(self, "_lo", lo.tolist())
        set_(self, "_hi", hi.tolist())
        for arr in (self.lower, self.upper, self.q_default, self.t0, self.R0, self.te, self.Re):
            arr.setflags(write=False)

    # ------------------------------------------------------------- forward
    def fk(self, root_p, root_R, q) -> tuple[np.ndarray, np.ndarray]:
        """Tip pose ``(p (N,3), R (N,3,3))`` for root poses and limb joints ``q (N,6)``.

        ``T_tip = T_root * P_0 * Rot_0(q0) * ... * P_5 * Rot_5(q5) * P_tip`` with the
        pinocchio joint placements ``P_i``; any of the inputs may be a single pose /
        6-vector and is broadcast.
        """
        root_p = _as_batch(root_p, (3,), "root_p")
        root_R = _as_batch(root_R, (3, 3), "root_R")
        q = _as_batch(q, (6,), "q")
        n = max(len(root_p), len(root_R), len(q))
        p = np.broadcast_to(root_p, (n, 3)).copy()
        R = np.broadcast_to(root_R, (n, 3, 3)).copy()
        q = np.broadcast_to(q, (n, 6))
        for k, (t, Rp) in enumerate(self._chain):
            p = p + R @ t
            R = (R @ Rp) @ _rot(self.axes[k], q[:, k])
        return p + R @ self.te, R @ self.Re

    def fk_se3(self, root: pin.SE3, q) -> pin.SE3:
        p, R = self.fk(root.translation, root.rotation, q)
        return pin.SE3(R[0], p[0])

    # ------------------------------------------------------------- inverse
    def solve(self, root_p, root_R, tip_p, tip_R, q_ref=None) -> IKResult:
        """Closed-form IK for N poses (formulas in the module docstring).

        ``root_p (N,3)``, ``root_R (N,3,3)``: world pose of the limb's root link;
        ``tip_p (N,3)``, ``tip_R (N,3,3)``: wanted world pose of the tip frame; a single
        pose ``(3,)`` / ``(3,3)`` is broadcast against the others (N=1 if all single).
        ``q_ref`` ``(N,6)`` or ``(6,)``: preferred posture; among the candidate
        branches within joint limits the one closest to it is returned (default
        ``self.q_default``, the half-sitting posture). It also fixes the free angle at
        exact singularities. Returns :class:`IKResult` with ``q`` of shape ``(N, 6)``.
        """
        root_p = _as_batch(root_p, (3,), "root_p")
        root_R = _as_batch(root_R, (3, 3), "root_R")
        tip_p = _as_batch(tip_p, (3,), "tip_p")
        tip_R = _as_batch(tip_R, (3, 3), "tip_R")
        ref = self.q_default[None] if q_ref is None else _as_batch(q_ref, (6,), "q_ref")
        arrs = [root_p, root_R, tip_p, tip_R, ref]
        n = max(len(a) for a in arrs)
        for k, a in enumerate(arrs):
            if len(a) != n:
                if len(a) != 1:
                    raise ValueError(f"inconsistent batch sizes: {[len(a) for a in arrs]} (each N or 1)")
                arrs[k] = np.broadcast_to(a, (n,) + a.shape[1:])
        if self.compiled and self.kind == "leg":
            return self._solve_compiled(n, *arrs)
        if n == 1:
            return self._solve_one(*(a[0].tolist() for a in arrs))
        return self._solve_batch(*arrs)

    def reach_centres(self, step_rad: float = 0.05) -> tuple[np.ndarray, float, float]:
        """The reach bound in the protocol's form (``GeneralLimb.reach_centres``): joint 0's
        origin ``t0``, no slack, ``l1 + l2`` (``step_rad``: unused, no joint swings the centre)."""
        return self.t0[None].copy(), 0.0, self.l1 + self.l2

    def maybe_reachable(self, root_p, root_R, tip_p, tip_R) -> np.ndarray:
        """Cheap necessary condition of :meth:`solve` success, (N,) bool, numpy-batched.

        ``False`` only where :meth:`solve` is certain to fail (UNREACHABLE or
        INVALID_INPUT): the reachability test of the closed form (module docstring:
        knee ``|cos q3| <= 1``, wrist pitch ``|k| <= rho``) on ``r = R_5^T (c - w)``,
        with a slack of ``REACH_SLACK`` above the solver's own tolerance so that
        rounding differences between this computation and the solver's can never
        drop a pose the solver accepts; NaN inputs give ``False`` (the solver
        rejects them too). Used to skip the full solve on the (many) goal samples
        whose hand is out of reach: the rows kept are solved exactly as before.
        Inputs as :meth:`solve` (N or 1 each, broadcast)."""
        root_p = _as_batch(root_p, (3,), "root_p")
        root_R = _as_batch(root_R, (3, 3), "root_R")
        tip_p = _as_batch(tip_p, (3,), "tip_p")
        tip_R = _as_batch(tip_R, (3, 3), "tip_R")
        c = root_p + root_R @ self.t0                                 # (N, 3)
        R5 = tip_R @ self.Re.T                                        # (N, 3, 3)
        w = tip_p - R5 @ self.te
        r = np.einsum("nji,nj->ni", R5, c - w)
        rr = np.einsum("ni,ni->n", r, r)
        with np.errstate(invalid="ignore"):
            if self.kind == "leg":
                A, B = self.l1, self.l2
                cq = (rr - A * A - B * B) / (2.0 * A * B)
                return np.abs(cq) <= 1.0 + REACH_TOL + REACH_SLACK
            U, F = self.l1, self.l2
            k = (rr + F * F - U * U) / (2.0 * F)
            rho = np.hypot(r[:, 0], r[:, 2])
            return rho - np.abs(k) >= -(REACH_TOL * rho + REACH_SLACK)

    def solve_reference(self, root_p, root_R, tip_p, tip_R, q_ref=None) -> IKResult:
        """:meth:`solve` by the reference implementation (numpy batch, pure Python for
        N = 1), whatever ``compiled`` says; used by the tests and ``--baseline`` benches."""
        if not self.compiled:
            return self.solve(root_p, root_R, tip_p, tip_R, q_ref)
        ref_ik = self.__dict__.get("_reference")
        if ref_ik is None:
            ref_ik = LimbIK(self.model, self.limb_name, compiled=False)
            object.__setattr__(self, "_reference", ref_ik)
        return ref_ik.solve(root_p, root_R, tip_p, tip_R, q_ref)

    def _solve_compiled(self, n: int, root_p, root_R, tip_p, tip_R, ref) -> IKResult:
        """The numba leg kernel :func:`_leg_ik_kernel` (legs only; inputs (N or 1, ...))."""
        q = np.empty((n, 6))
        ok = np.empty(n, np.bool_)
        reason = np.empty(n, np.int8)
        branch = np.empty(n, np.int64)
        _leg_ik_kernel(_kernel_arg(root_p), _kernel_arg(root_R), _kernel_arg(tip_p), _kernel_arg(tip_R),
                       _kernel_arg(ref), *self._kc, q, ok, reason, branch)
        return IKResult(q=q, ok=ok, reason=reason, branch=branch)

    def _solve_batch(self, root_p, root_R, tip_p, tip_R, ref) -> IKResult:
        """The numpy-batched solver (inputs already (N, ...) with equal N)."""
        valid = np.isfinite(root_p.sum(1) + tip_p.sum(1) + ref.sum(1))
        valid &= _valid_rotation(root_R) & _valid_rotation(tip_R)
        if not valid.all():
            v = valid[:, None]
            root_p, tip_p = np.where(v, root_p, 0.0), np.where(v, tip_p, 0.0)
            root_R = np.where(v[..., None], root_R, np.eye(3))
            tip_R = np.where(v[..., None], tip_R, np.eye(3))
            ref = np.where(v, ref, self.q_default)

        # first joint centre / frame, last link frame / origin, r = R5^T (c - w)
        Rc = root_R @ self.R0
        c = root_p + root_R @ self.t0
        R5 = tip_R @ self.Re.T
        w = tip_p - R5 @ self.te
        r = np.einsum("nji,nj->ni", R5, c - w)
        # hip/shoulder rotation seen from the last link: M_total = Rc^T R5
        Mt = np.einsum("nji,njk->nik", Rc, R5)
        with np.errstate(invalid="ignore", divide="ignore"):
            if self.kind == "leg":
                Q, reach, pairs = self._solve_leg(r, Mt, ref)
            else:
                Q, reach, pairs = self._solve_arm(r, Mt, ref)
        return self._select(Q, reach, pairs, valid, ref)

    def solve_se3(self, root: pin.SE3, tip: pin.SE3, q_ref=None) -> IKResult:
        """Single-pose convenience wrapper of :meth:`solve` (N = 1)."""
        return self.solve(root.translation, root.rotation, tip.translation, tip.rotation, q_ref)

    # ------------------------------------------------------------- internals
    @staticmethod
    def _cos_angle(num: np.ndarray, den: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """cos of the knee/elbow (law of cosines), |sin|, and the reachability flag."""
        cq = num / den
        reach = np.abs(cq) <= 1.0 + REACH_TOL
        cq = np.clip(cq, -1.0, 1.0)
        sq = np.sqrt((1.0 - cq) * (1.0 + cq))
        return cq, sq, reach

    def _solve_leg(self, r, Mt, ref):
        A, B = self.l1, self.l2
        n = len(r)
        c3, s3, reach = self._cos_angle(np.einsum("ni,ni->n", r, r) - A * A - B * B, 2.0 * A * B)
        s3b = np.stack([s3, -s3], axis=1)                        # (N,2) knee branches
        q3 = np.arctan2(s3b, c3[:, None])
        # ankle roll: Rx(q5) r has no y component
        free5 = np.hypot(r[:, 1], r[:, 2]) < SINGULAR_TOL        # hip on the ankle-roll axis
        q5a = np.where(free5, ref[:, 5], np.arctan2(r[:, 1], r[:, 2]))
        q5 = np.stack([q5a, q5a + np.pi], axis=1)                # (N,2) roll branches
        vz = np.sin(q5) * r[:, 1:2] + np.cos(q5) * r[:, 2:3]     # (N,2)
        q4 = (np.arctan2(-A * s3b, A * c3[:, None] + B)[:, :, None]
              - np.arctan2(r[:, 0:1], vz)[:, None, :])            # (N,2,2)
        q3x = np.broadcast_to(q3[:, :, None], (n, 2, 2))
        q5x = np.broadcast_to(q5[:, None, :], (n, 2, 2))
        # hip: Rz(q0) Rx(q1) Ry(q2) = Mt Rx(-q5) Ry(-(q3+q4))
        M = Mt[:, None, None] @ _rot("x", -q5x) @ _rot("y", -(q3x + q4))   # (N,2,2,3,3)
        gimbal = np.hypot(M[..., 0, 1], M[..., 1, 1]) < GIMBAL_TOL
        q0a = np.where(gimbal, ref[:, None, None, 0], np.arctan2(-M[..., 0, 1], M[..., 1, 1]))
        q0 = np.stack([q0a, q0a + np.pi], axis=-1)               # (N,2,2,2)
        ca, sa = np.cos(q0), np.sin(q0)
        Me = M[:, :, :, None]                                    # (N,2,2,1,3,3)
        n00 = ca * Me[..., 0, 0] + sa * Me[..., 1, 0]
        n02 = ca * Me[..., 0, 2] + sa * Me[..., 1, 2]
        n11 = -sa * Me[..., 0, 1] + ca * Me[..., 1, 1]
        q2 = np.arctan2(n02, n00)
        q1 = np.arctan2(Me[..., 2, 1], n11)
        # at gimbal lock snap the roll to exactly +-pi/2 (error <= GIMBAL_TOL) so that
        # moving along the free direction below is exact
        q1 = np.where(gimbal[..., None], np.copysign(0.5 * np.pi, q1), q1)
        e = q0.shape
        Q = np.empty(e + (6,))
        Q[..., 0], Q[..., 1], Q[..., 2] = q0, q1, q2
        Q[..., 3], Q[..., 4], Q[..., 5] = q3x[..., None], q4[..., None], q5x[..., None]
        # gimbal lock (hip roll +-90 deg): Rz(q0) Rx(+-pi/2) Ry(q2) depends on
        # q0 + sin(q1) q2 only -> move along (q0, q2) = (+d, -sin(q1) d)
        pairs = [(np.broadcast_to(gimbal[..., None], e).reshape(n, 8), 0, 2, -np.sin(q1).reshape(n, 8))]
        return Q.reshape(n, 8, 6), reach, pairs

    def _solve_arm(self, r, Mt, ref):
        U, F = self.l1, self.l2
        n = len(r)
        # wrist pitch: the forearm direction f = Ry(-q5) e_z must satisfy
        # |r - F f| = U, i.e. r.f = r_z cos q5 - r_x sin q5 = k := (|r|^2 + F^2 - U^2) / 2F
        # (k = U cos q3 + F); with rho = hypot(r_x, r_z), phi = atan2(r_x, r_z):
        # q5 = -phi +- psi, cos psi = k / rho.
        rr = np.einsum("ni,ni->n", r, r)
        k = (rr + F * F - U * U) / (2.0 * F)
        rho = np.hypot(r[:, 0], r[:, 2])
        phi = np.arctan2(r[:, 0], r[:, 2])
        gap = rho - np.abs(k)                                    # >= 0 iff reachable
        reach = gap >= -REACH_TOL * rho
        cpsi = np.clip(k / np.where(rho > 0.0, rho, 1.0), -1.0, 1.0)
        # on the tangent (|k| ~ rho: arm stretched, or wrist yaw +-90 deg) psi is
        # sqrt-conditioned; snapping it costs at most F gap / U < PSI_SNAP in position
        cpsi = np.where(gap < PSI_SNAP, np.sign(k), cpsi)
        psi = np.arctan2(np.sqrt((1.0 - cpsi) * (1.0 + cpsi)), cpsi)
        q5 = np.stack([-phi + psi, -phi - psi], axis=1)          # (N,2) wrist-pitch branches
        c5, s5 = np.cos(q5), np.sin(q5)
        # upper-arm vector in the wrist-yaw frame: t = Ry(q5) r - F e_z
        #   = Rz(-q4) Ry(-q3) (0, 0, U) = (-U s3 c4, U s3 s4, U c3)
        # elbow and wrist yaw both come from t, so they stay consistent with q5
        tx = c5 * r[:, 0:1] + s5 * r[:, 2:3]
        ty = np.broadcast_to(r[:, 1:2], tx.shape)
        tz = -s5 * r[:, 0:1] + c5 * r[:, 2:3] - F
        h = np.hypot(tx, ty)                                     # U |sin q3|, (N,2)
        q3p = np.arctan2(h, tz)
        q4p = np.arctan2(ty, -tx)
        stretched = h < STRETCH_TOL                              # wrist yaw // shoulder yaw
        q3p = np.where(stretched, 0.0, q3p)
        q4p = np.where(stretched, ref[:, 4:5], q4p)
        q3 = np.stack([q3p, -q3p], axis=1)                       # (N,2 elbow,2 wrist)
        q4 = np.stack([q4p, np.where(stretched, q4p, q4p + np.pi)], axis=1)
        q5x = np.broadcast_to(q5[:, None, :], (n, 2, 2))
        # shoulder: Ry(q0) Rx(q1) Rz(q2) = Mt Ry(-q5) Rz(-q4) Ry(-q3)
        M = Mt[:, None, None] @ _rot("y", -q5x) @ _rot("z", -q4) @ _rot("y", -q3)   # (N,2,2,3,3)
        gimbal = np.hypot(M[..., 0, 2], M[..., 2, 2]) < GIMBAL_TOL
        q0a = np.where(gimbal, ref[:, None, None, 0], np.arctan2(M[..., 0, 2], M[..., 2, 2]))
        q0 = np.stack([q0a, q0a + np.pi], axis=-1)               # (N,2,2,2)
        ca, sa = np.cos(q0), np.sin(q0)
        Me = M[:, :, :, None]
        n00 = ca * Me[..., 0, 0] - sa * Me[..., 2, 0]
        n01 = ca * Me[..., 0, 1] - sa * Me[..., 2, 1]
        n22 = sa * Me[..., 0, 2] + ca * Me[..., 2, 2]
        q2 = np.arctan2(-n01, n00)
        q1 = np.arctan2(-Me[..., 1, 2], n22)
        q1 = np.where(gimbal[..., None], np.copysign(0.5 * np.pi, q1), q1)   # see _solve_leg
        e = q0.shape
        Q = np.empty(e + (6,))
        Q[..., 0], Q[..., 1], Q[..., 2] = q0, q1, q2
        Q[..., 3], Q[..., 4], Q[..., 5] = q3[..., None], q4[..., None], q5x[..., None]
        # exact singularities leave one angle free; move along the invariant direction:
        # gimbal lock (shoulder roll +-90 deg): Ry(q0) Rx(+-pi/2) Rz(q2) depends on
        #   q2 - sin(q1) q0 only -> (q0, q2) += (d, sin(q1) d)
        # stretched arm (q3 = 0): Rz(q2) Rz(q4) depends on q2 + q4 -> (q4, q2) += (d, -d)
        pairs = [
            (np.broadcast_to(gimbal[..., None], e).reshape(n, 8), 0, 2, np.sin(q1).reshape(n, 8)),
            (np.broadcast_to(stretched[:, None, :, None], e).reshape(n, 8), 4, 2, np.full((n, 8), -1.0)),
        ]
        return Q.reshape(n, 8, 6), reach, pairs

    def _redistribute(self, Qw, mask, i, j, coef, ref) -> None:
        """At an exact singularity only ``q_i + q_j / coef`` (coef = +-1) is fixed:
        pick ``d`` for ``(q_i, q_j) += (d, coef d)`` within both joints' limits (trying
        the 2 pi shifts of ``q_j``) and closest to ``ref``. In place on ``Qw``."""
        rows, br = np.nonzero(mask)
        if rows.size == 0:
            return
        lo, hi = self.lower, self.upper
        q = Qw[rows, br]
        rf = ref[rows]
        c = np.sign(coef[rows, br])
        c = np.where(c == 0.0, 1.0, c)
        qi, qj = q[:, i], q[:, j]
        best = np.full(rows.size, np.inf)
        d_best = np.zeros(rows.size)
        qj_best = qj.copy()
        for m in (-2, -1, 0, 1, 2):
            qjm = qj + TWO_PI * m
            e1, e2 = c * (lo[j] - qjm), c * (hi[j] - qjm)
            a = np.maximum(lo[i] - qi, np.minimum(e1, e2))
            b = np.minimum(hi[i] - qi, np.maximum(e1, e2))
            d = np.clip(0.5 * ((rf[:, i] - qi) + c * (rf[:, j] - qjm)), a, b)
            cost = (qi + d - rf[:, i]) ** 2 + (qjm + c * d - rf[:, j]) ** 2
            upd = (a <= b) & (cost < best)
            best = np.where(upd, cost, best)
            d_best = np.where(upd, d, d_best)
            qj_best = np.where(upd, qjm, qj_best)
        found = np.isfinite(best)
        q[found, i] = qi[found] + d_best[found]
        q[found, j] = qj_best[found] + c[found] * d_best[found]
        Qw[rows, br] = q

    def _wrap(self, Q: np.ndarray) -> np.ndarray:
        base = self.lower - LIMIT_TOL
        return base + np.mod(Q - base, TWO_PI)                   # representative >= lower

    def _select(self, Q, reach, pairs, valid, ref) -> IKResult:
        lo, hi = self.lower, self.upper
        Qw = self._wrap(Q)
        if any(mask.any() for mask, *_ in pairs):
            for mask, i, j, coef in pairs:
                self._redistribute(Qw, mask, i, j, coef, ref)
            Qw = self._wrap(Qw)
        inlim = np.all(np.isfinite(Qw) & (Qw <= hi + LIMIT_TOL), axis=-1)   # (N,8)
        cand = inlim & (reach & valid)[:, None]
        Qw = np.clip(Qw, lo, hi)
        d = np.where(cand, np.sum((Qw - ref[:, None, :]) ** 2, axis=-1), np.inf)
        best = np.argmin(d, axis=1)
        ok = cand.any(axis=1)
        n = len(Q)
        q = np.where(ok[:, None], Qw[np.arange(n), best], np.nan)
        reason = np.full(n, IKReason.JOINT_LIMITS, dtype=np.int8)
        reason[ok] = IKReason.OK
        reason[~reach & ~ok] = IKReason.UNREACHABLE
        reason[~valid] = IKReason.INVALID_INPUT
        return IKResult(q=q, ok=ok, reason=reason, branch=np.where(ok, best, -1))

    # ------------------------------------------------------------- single pose
    # The same algorithm as _solve_leg / _solve_arm / _select, written with Python
    # floats and math: for N = 1 it is several times faster than numpy on tiny arrays.
    # test_limb_ik.py checks that both paths agree.
    def _solve_one(self, root_p, root_R, tip_p, tip_R, ref) -> IKResult:
        vals = root_p + tip_p + ref + [x for row in root_R + tip_R for x in row]
        if not (all(map(math.isfinite, vals)) and _rot_ok(root_R) and _rot_ok(tip_R)):
            return _fail1(IKReason.INVALID_INPUT)
        R0, t0, Re, te = self._py
        Rc = _mm(root_R, R0)
        c = [root_p[i] + root_R[i][0] * t0[0] + root_R[i][1] * t0[1] + root_R[i][2] * t0[2] for i in range(3)]
        R5 = _mmt(tip_R, Re)
        w = [tip_p[i] - R5[i][0] * te[0] - R5[i][1] * te[1] - R5[i][2] * te[2] for i in range(3)]
        d = [c[0] - w[0], c[1] - w[1], c[2] - w[2]]
        r = [R5[0][i] * d[0] + R5[1][i] * d[1] + R5[2][i] * d[2] for i in range(3)]
        Mt = _mtm(Rc, R5)
        if self.kind == "leg":
            cands, reach = self._leg_one(r, Mt, ref)
        else:
            cands, reach = self._arm_one(r, Mt, ref)
        if not reach:
            return _fail1(IKReason.UNREACHABLE)
        lo, hi = self._lo, self._hi
        best, best_d, best_q = -1, math.inf, None
        for b, (q, pairs) in enumerate(cands):
            q = [lo[i] - LIMIT_TOL + (q[i] - lo[i] + LIMIT_TOL) % TWO_PI for i in range(6)]
            if pairs:
                for i, j, coef in pairs:
                    redistribute_pair.py_func(q, i, j, coef, ref, lo, hi)   # the same code, uncompiled
                q = [lo[i] - LIMIT_TOL + (q[i] - lo[i] + LIMIT_TOL) % TWO_PI for i in range(6)]
            if not all(q[i] <= hi[i] + LIMIT_TOL for i in range(6)):   # NaN fails too
                continue
            q = [min(max(q[i], lo[i]), hi[i]) for i in range(6)]
            dist = sum((q[i] - ref[i]) ** 2 for i in range(6))
            if dist < best_d:
                best, best_d, best_q = b, dist, q
        if best < 0:
            return _fail1(IKReason.JOINT_LIMITS)
        return IKResult(q=np.array([best_q]), ok=np.ones(1, bool),
                        reason=np.zeros(1, np.int8), branch=np.array([best]))

    def _leg_one(self, r, Mt, ref):
        A, B = self.l1, self.l2
        c3 = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] - A * A - B * B) / (2.0 * A * B)
        if not abs(c3) <= 1.0 + REACH_TOL:
            return [], False
        c3 = min(max(c3, -1.0), 1.0)
        s3 = math.sqrt((1.0 - c3) * (1.0 + c3))
        q5a = ref[5] if math.hypot(r[1], r[2]) < SINGULAR_TOL else math.atan2(r[1], r[2])
        cands = []
        for s3i in (s3, -s3):
            q3 = math.atan2(s3i, c3)
            alpha = math.atan2(-A * s3i, A * c3 + B)
            for q5 in (q5a, q5a + math.pi):
                q4 = alpha - math.atan2(r[0], math.sin(q5) * r[1] + math.cos(q5) * r[2])
                M = _rmul(_rmul(Mt, "x", -q5), "y", -(q3 + q4))
                gimbal = math.hypot(M[0][1], M[1][1]) < GIMBAL_TOL
                q0a = ref[0] if gimbal else math.atan2(-M[0][1], M[1][1])
                for q0 in (q0a, q0a + math.pi):
                    ca, sa = math.cos(q0), math.sin(q0)
                    q2 = math.atan2(ca * M[0][2] + sa * M[1][2], ca * M[0][0] + sa * M[1][0])
                    q1 = math.atan2(M[2][1], -sa * M[0][1] + ca * M[1][1])
                    pairs = None
                    if gimbal:
                        q1 = math.copysign(0.5 * math.pi, q1)
                        pairs = [(0, 2, -math.sin(q1))]
                    cands.append(([q0, q1, q2, q3, q4, q5], pairs))
        return cands, True

    def _arm_one(self, r, Mt, ref):
        U, F = self.l1, self.l2
        k = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + F * F - U * U) / (2.0 * F)
        rho = math.hypot(r[0], r[2])
        phi = math.atan2(r[0], r[2])
        gap = rho - abs(k)
        if not gap >= -REACH_TOL * rho:
            return [], False
        cpsi = min(max(k / (rho if rho > 0.0 else 1.0), -1.0), 1.0)
        if gap < PSI_SNAP:
            cpsi = math.copysign(1.0, k) if k != 0.0 else 0.0
        psi = math.atan2(math.sqrt((1.0 - cpsi) * (1.0 + cpsi)), cpsi)
        per_wrist = []
        for q5 in (-phi + psi, -phi - psi):
            c5, s5 = math.cos(q5), math.sin(q5)
            tx = c5 * r[0] + s5 * r[2]
            ty = r[1]
            tz = -s5 * r[0] + c5 * r[2] - F
            h = math.hypot(tx, ty)
            stretched = h < STRETCH_TOL
            q3p = 0.0 if stretched else math.atan2(h, tz)
            q4p = ref[4] if stretched else math.atan2(ty, -tx)
            per_wrist.append((q5, q3p, q4p, stretched))
        cands = []
        for i in (0, 1):                      # elbow branch
            for q5, q3p, q4p, stretched in per_wrist:
                q3 = q3p if i == 0 else -q3p
                q4 = q4p if (i == 0 or stretched) else q4p + math.pi
                M = _rmul(_rmul(_rmul(Mt, "y", -q5), "z", -q4), "y", -q3)
                gimbal = math.hypot(M[0][2], M[2][2]) < GIMBAL_TOL
                q0a = ref[0] if gimbal else math.atan2(M[0][2], M[2][2])
                for q0 in (q0a, q0a + math.pi):
                    ca, sa = math.cos(q0), math.sin(q0)
                    q2 = math.atan2(-(ca * M[0][1] - sa * M[2][1]), ca * M[0][0] - sa * M[2][0])
                    q1 = math.atan2(-M[1][2], sa * M[0][2] + ca * M[2][2])
                    pairs = []
                    if gimbal:
                        q1 = math.copysign(0.5 * math.pi, q1)
                        pairs.append((0, 2, math.sin(q1)))
                    if stretched:
                        pairs.append((4, 2, -1.0))
                    cands.append(([q0, q1, q2, q3, q4, q5], pairs or None))
        return cands, True


# ----------------------------------------------------------------- scalar helpers
def _fail1(reason: IKReason) -> IKResult:
    return IKResult(q=np.full((1, 6), np.nan), ok=np.zeros(1, bool),
                    reason=np.array([int(reason)], np.int8), branch=np.array([-1]))


def _mm(A, B):
    return [[A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3)] for i in range(3)]


def _mmt(A, B):   # A B^T
    return [[A[i][0] * B[j][0] + A[i][1] * B[j][1] + A[i][2] * B[j][2] for j in range(3)] for i in range(3)]


def _mtm(A, B):   # A^T B
    return [[A[0][i] * B[0][j] + A[1][i] * B[1][j] + A[2][i] * B[2][j] for j in range(3)] for i in range(3)]


def _rmul(M, axis: str, ang: float):
    """M @ R_axis(ang) by column operations."""
    i, j, _ = _PLANE[axis]
    c, s = math.cos(ang), math.sin(ang)
    out = [list(row) for row in M]
    for row_out, row in zip(out, M):
        row_out[i] = c * row[i] + s * row[j]
        row_out[j] = -s * row[i] + c * row[j]
    return out


def _rot_ok(R) -> bool:
    for a in range(3):
        for b in range(a, 3):
            dot = R[0][a] * R[0][b] + R[1][a] * R[1][b] + R[2][a] * R[2][b]
            if not abs(dot - (1.0 if a == b else 0.0)) <= ROTATION_TOL:
                return False
    det = (R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
           - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
           + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0]))
    return det > 0.0


# ----------------------------------------------------------------- compiled leg IK
# The leg solver of LimbIK._solve_leg + _select (+ _redistribute) as one numba kernel,
# one pose at a time, no temporaries: the planner projects every RRT node / edge
# point through both legs, in many small batches, where numpy's per-call overhead
# dominated. Same formulas, branch order (4 knee + 2 roll + hip), tolerances and
# tie-breaking; test_limb_ik.py checks it against the numpy reference to 1e-12.
@nb.njit(**_JIT)
def wrap_angle(x, lo):
    """``x`` wrapped into ``[lo - LIMIT_TOL, lo - LIMIT_TOL + 2 pi)`` (compiled legs and arms)."""
    base = lo - LIMIT_TOL
    return base + (x - base) % TWO_PI


@nb.njit(**_JIT)
def redistribute_pair(q, i, j, coef, ref, lo, hi):
    """Gimbal redistribution, in place on ``q`` (an array, or the scalar path's list through
    ``redistribute_pair.py_func``; twin of :meth:`LimbIK._redistribute`): at a gimbal
    lock only ``q_i + coef q_j`` is fixed; move ``(q_i, q_j) += (d, sign(coef) d)`` (``q_j``
    also by whole turns) within the limits, closest to ``ref``. Legs and arms
    (``kinematics/hand_derived_compiled.py``) alike."""
    c = 1.0 if coef >= 0.0 else -1.0
    qi, qj = q[i], q[j]
    best = np.inf
    d_best = 0.0
    qj_best = qj
    for m in range(-2, 3):
        qjm = qj + TWO_PI * m
        e1, e2 = c * (lo[j] - qjm), c * (hi[j] - qjm)
        a = max(lo[i] - qi, min(e1, e2))
        b = min(hi[i] - qi, max(e1, e2))
        if a > b:
            continue
        d = min(max(0.5 * ((ref[i] - qi) + c * (ref[j] - qjm)), a), b)
        cost = (qi + d - ref[i]) ** 2 + (qjm + c * d - ref[j]) ** 2
        if cost < best:
            best, d_best, qj_best = cost, d, qjm
    if best < np.inf:
        q[i] = qi + d_best
        q[j] = qj_best + c * d_best


@nb.njit(**_JIT)
def _leg_rot_ok(R):
    """Twin of :func:`_valid_rotation` for one matrix."""
    err = 0.0
    for a in range(3):
        for b in range(3):
            d = R[0, a] * R[0, b] + R[1, a] * R[1, b] + R[2, a] * R[2, b]
            e = abs(d - (1.0 if a == b else 0.0))
            if not e <= err:       # NaN counts as "bad"
                err = e if e == e else np.inf
    det = ((R[0, 1] * R[1, 2] - R[0, 2] * R[1, 1]) * R[2, 0]
           + (R[0, 2] * R[1, 0] - R[0, 0] * R[1, 2]) * R[2, 1]
           + (R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0]) * R[2, 2])
    return err <= ROTATION_TOL and det > 0.0


@nb.njit(**_JIT)
def _leg_ik_kernel(root_p, root_R, tip_p, tip_R, ref, R0, t0, Re, te, A, B, lo, hi,
                   out_q, out_ok, out_reason, out_branch):
    """Closed-form leg IK of N poses (inputs with a leading dimension N or 1)."""
    n = out_q.shape[0]
    work = np.empty(LEG_WORK_SIZE)
    for k in range(n):
        ir = k if root_p.shape[0] > 1 else 0
        iR = k if root_R.shape[0] > 1 else 0
        it = k if tip_p.shape[0] > 1 else 0
        iT = k if tip_R.shape[0] > 1 else 0
        jf = k if ref.shape[0] > 1 else 0
        reason, branch = leg_ik_pose(root_p[ir], root_R[iR], tip_p[it], tip_R[iT], ref[jf], R0, t0, Re, te, A, B,
                                     lo, hi, out_q[k], work)
        out_ok[k] = reason == 0
        out_reason[k] = reason
        out_branch[k] = branch


@nb.njit(**_JIT)
def _drop_hip_branches(Q, gim, first):
    """Branches ``first`` and ``first + 1`` (both hip solutions) have no solution: NaN rows."""
    for b in range(first, first + 2):
        gim[b] = 0.0
        for a in range(6):
            Q[b, a] = np.nan


@nb.njit(**_JIT)
def leg_ik_pose(rp, rR, tp, tR, rf, R0, t0, Re, te, A, B, lo, hi, q_out, work):
    """One leg pose: writes ``q_out`` (6,) (NaN on failure); returns ``(reason, branch)``
    (:class:`IKReason` code, branch index or -1). ``R0, t0, Re, te, A = l1, B = l2, lo,
    hi``: the :class:`LimbIK` constants (``LimbIK._kc``); ``work``: float scratch of
    ``LEG_WORK_SIZE``. For other numba kernels (the planner's fused projection) and
    :func:`_leg_ik_kernel`."""
    s = (rp[0] + rp[1] + rp[2]) + (tp[0] + tp[1] + tp[2]) + (rf[0] + rf[1] + rf[2] + rf[3] + rf[4] + rf[5])
    if not (np.isfinite(s) and _leg_rot_ok(rR) and _leg_rot_ok(tR)):
        for a in range(6):
            q_out[a] = np.nan
        return 3, -1             # INVALID_INPUT
    # scratch views of `work` (no allocation per pose)
    Rc = work[0:9].reshape((3, 3))
    R5 = work[9:18].reshape((3, 3))
    Mt = work[18:27].reshape((3, 3))
    M1 = work[27:36].reshape((3, 3))
    M = work[36:45].reshape((3, 3))
    c = work[45:48]
    w = work[48:51]
    r = work[51:54]
    Q = work[54:102].reshape((8, 6))
    gim = work[102:110]          # 1.0 where the branch is at gimbal lock
    # Rc = root_R R0, c = root_p + root_R t0, R5 = tip_R Re^T, w = tip_p - R5 te
    for a in range(3):
        for b in range(3):
            Rc[a, b] = rR[a, 0] * R0[0, b] + rR[a, 1] * R0[1, b] + rR[a, 2] * R0[2, b]
            R5[a, b] = tR[a, 0] * Re[b, 0] + tR[a, 1] * Re[b, 1] + tR[a, 2] * Re[b, 2]
        c[a] = rp[a] + (rR[a, 0] * t0[0] + rR[a, 1] * t0[1] + rR[a, 2] * t0[2])
    for a in range(3):
        w[a] = tp[a] - (R5[a, 0] * te[0] + R5[a, 1] * te[1] + R5[a, 2] * te[2])
    d0, d1, d2 = c[0] - w[0], c[1] - w[1], c[2] - w[2]
    for a in range(3):
        r[a] = R5[0, a] * d0 + R5[1, a] * d1 + R5[2, a] * d2
        for b in range(3):
            Mt[a, b] = Rc[0, a] * R5[0, b] + Rc[1, a] * R5[1, b] + Rc[2, a] * R5[2, b]
    # knee (law of cosines), 2 branches
    c3 = ((r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) - A * A - B * B) / (2.0 * A * B)
    reach = abs(c3) <= 1.0 + REACH_TOL
    if not reach:
        for a in range(6):
            q_out[a] = np.nan
        return 1, -1             # UNREACHABLE
    c3 = min(max(c3, -1.0), 1.0)
    s3 = math.sqrt((1.0 - c3) * (1.0 + c3))
    # ankle roll, 2 branches
    if math.hypot(r[1], r[2]) < SINGULAR_TOL:
        q5a = rf[5]
    else:
        q5a = math.atan2(r[1], r[2])
    any_gim = False
    # A candidate whose knee, ankle pitch or ankle roll is outside its limits (after
    # wrapping) can never be selected (the gimbal redistribution only moves q0, q2):
    # its hip angles are not computed (row set to NaN, which fails the limit test).
    for kb in range(2):
        s3b = s3 if kb == 0 else -s3
        q3 = math.atan2(s3b, c3)
        q3w = wrap_angle(q3, lo[3])
        knee_out = not (q3w <= hi[3] + LIMIT_TOL)
        alpha = math.atan2(-A * s3b, A * c3 + B)
        for rb in range(2):
            q5 = q5a if rb == 0 else q5a + np.pi
            q5w = wrap_angle(q5, lo[5])
            if knee_out or not (q5w <= hi[5] + LIMIT_TOL):
                _drop_hip_branches(Q, gim, 4 * kb + 2 * rb)
                continue
            vz = math.sin(q5) * r[1] + math.cos(q5) * r[2]
            q4 = alpha - math.atan2(r[0], vz)
            q4w = wrap_angle(q4, lo[4])
            if not (q4w <= hi[4] + LIMIT_TOL):
                _drop_hip_branches(Q, gim, 4 * kb + 2 * rb)
                continue
            # M = Mt Rx(-q5) Ry(-(q3 + q4))
            cx, sx = math.cos(-q5), math.sin(-q5)
            th = -(q3 + q4)
            cy, sy = math.cos(th), math.sin(th)
            for a in range(3):
                M1[a, 0] = Mt[a, 0]
                M1[a, 1] = Mt[a, 1] * cx + Mt[a, 2] * sx
                M1[a, 2] = -Mt[a, 1] * sx + Mt[a, 2] * cx
            for a in range(3):
                M[a, 0] = M1[a, 0] * cy - M1[a, 2] * sy
                M[a, 1] = M1[a, 1]
                M[a, 2] = M1[a, 0] * sy + M1[a, 2] * cy
            gimbal = math.hypot(M[0, 1], M[1, 1]) < GIMBAL_TOL
            if gimbal:
                q0a = rf[0]
                any_gim = True
            else:
                q0a = math.atan2(-M[0, 1], M[1, 1])
            for hb in range(2):
                q0 = q0a if hb == 0 else q0a + np.pi
                ca, sa = math.cos(q0), math.sin(q0)
                n00 = ca * M[0, 0] + sa * M[1, 0]
                n02 = ca * M[0, 2] + sa * M[1, 2]
                n11 = -sa * M[0, 1] + ca * M[1, 1]
                q2 = math.atan2(n02, n00)
                q1 = math.atan2(M[2, 1], n11)
                if gimbal:
                    q1 = math.copysign(0.5 * np.pi, q1)
                b = 4 * kb + 2 * rb + hb
                gim[b] = 1.0 if gimbal else 0.0
                Q[b, 0] = wrap_angle(q0, lo[0])
                Q[b, 1] = wrap_angle(q1, lo[1])
                Q[b, 2] = wrap_angle(q2, lo[2])
                Q[b, 3] = q3w
                Q[b, 4] = q4w
                Q[b, 5] = q5w
    if any_gim:
        # gimbal lock: only q0 + sin(q1) q2 fixed; move (q0, q2) += (d, coef d) with
        # coef = -sin(q1), within the limits, closest to ref (LimbIK._redistribute)
        for b in range(8):
            if gim[b] == 0.0:
                continue
            redistribute_pair(Q[b], 0, 2, -math.sin(Q[b, 1]), rf, lo, hi)
            for a in range(6):
                Q[b, a] = wrap_angle(Q[b, a], lo[a])
    best_b = -1
    best_d = np.inf
    if reach:   # (always here: unreachable returned above)
        for b in range(8):
            inlim = True
            for a in range(6):
                if not (Q[b, a] <= hi[a] + LIMIT_TOL):     # NaN fails too
                    inlim = False
                    break
            if not inlim:
                continue
            dist = 0.0
            for a in range(6):
                Q[b, a] = min(max(Q[b, a], lo[a]), hi[a])
                dist += (Q[b, a] - rf[a]) ** 2
            if dist < best_d:
                best_d = dist
                best_b = b
    if best_b < 0:
        for a in range(6):
            q_out[a] = np.nan
        return (2 if reach else 1), -1       # JOINT_LIMITS / UNREACHABLE
    for a in range(6):
        q_out[a] = Q[best_b, a]
    return 0, best_b


def _kernel_arg(a: np.ndarray) -> np.ndarray:
    """A batch argument as a writable C-contiguous float array; a broadcast one
    (stride 0 along N) is passed as its single row (the kernel broadcasts N = 1)."""
    if a.shape[0] > 1 and a.strides[0] == 0:
        a = a[:1]
    if not (a.flags.c_contiguous and a.flags.writeable and a.dtype == np.float64):
        a = np.array(a, dtype=np.float64, order="C")
    return a


def warm_up() -> None:
    """Compile (or load from the numba cache) the leg kernel on a tiny batch (every limb
    solver's kernels: ``kinematics.registry.warm_up``)."""
    eye = np.eye(3)[None]
    z = np.zeros((1, 3))
    out = (np.empty((1, 6)), np.empty(1, np.bool_), np.empty(1, np.int8), np.empty(1, np.int64))
    _leg_ik_kernel(z, eye, z - [0.0, 0.0, 0.6], eye, np.zeros((1, 6)), eye[0], z[0], eye[0], z[0], 0.3, 0.3,
                   np.full(6, -3.0), np.full(6, 3.0), *out)
