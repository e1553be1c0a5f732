"""Retreat from a contact: the first stage of a plan that starts with a hand on something.

After a reach the hand rests on (or in) the object it reached: a valve whose voxels are in
the map. Every plan from there used to fail with ``START_IN_COLLISION``, for either arm
(the start check, or the pre-segment that moves the trunk and the other arm to the planning
manifold dragging the hand through the object). MoveIt 2 refuses such a start
(CheckStartStateCollision; its old random "jiggle" moved arms 10-40 cm); MoveIt Task
Constructor plans an explicit retreat stage (MoveRelative, 0.12-0.25 m). This module is
that stage for a humanoid:

1. **Contact** (:meth:`RetreatPlanner.classify_start`): the start is *in contact* when a
   shape of a hand (:func:`hand_shape_mask`: forearm, wrist and hand, the links below the
   elbow) is within ``contact_distance_m`` (5 cm) of the occupied voxels, or penetrates them
   (a hand at a valve's centre is 3.5 cm from the ring's voxels, enclosed by them). Any other shape that
   penetrates the map makes the start a real collision: no retreat, the caller answers
   ``START_IN_COLLISION`` naming the links and the nearest voxels.
2. **Directions**, in order: the reverse of the approach (when the caller knows it), the
   contact normal ``n = (p_hand - c) / |p_hand - c|`` with ``c`` the centroid of the
   voxels within ``contact_radius_m`` of the hand, that normal tilted up, and straight
   back toward the shoulder.
3. **Motion**: first back along the last plan's own samples when the robot stands at its end
   (the way the hand came in is a way out; "at its end": the hand within 3 cm of the plan's,
   no joint 0.5 rad off, the offset blended out along the way back: ``ReachPlanner.
   _reverse_of_last``), else along a direction ``d``: the hand frame
   moves on the line ``p(s) = p_0 + s d``, ``s`` in steps of ``step_m`` up to
   ``max_distance_m``; the arm's joints follow by damped least squares on the hand's position
   error and, weighted by ``orientation_weight``, its orientation error
   (``dq = J^T (J J^T + lambda^2 I)^-1 e``, a few iterations a step and up to three more
   rounds where the line is not reached yet, clipped to the joint limits; the line must be
   kept within 2 mm), every other joint
   and the base stay (feet fixed; the executor's exact-COG task compensates the arm's
   mass). The chest joints move with the arm; a named simplification: the legs and the
   waist do not help the retreat.
4. **Checks** at every step: joint limits; no shape other than the hand's penetrates the
   map; no pair of the robot's own shapes comes within the planner's self-collision margin
   that was not that close at the start (a chest brought home once swung the other forearm
   into the waist); the hand's shapes touch only the voxels within ``contact_radius_m`` of the contact
   (the allowed contact) and never press into them deeper than at the start (never into them
   at all when the start is clear of them; ``clearance_tolerance_m``) -- on the way back along
   the approach, ``way_back_depth_m`` (15 mm) deeper: the planner left the voxels around the
   target out, so the way in grazed the object deeper than where the hand rests (since
   planning/approach.py a path goes no deeper than its goal, within 3 mm: the allowance is now for
   the executor's deviation from the plan and the spline between checked points; Talos's gripper
   at the valve's rim: 38 mm in at its end, 40-48 mm at the samples before; in the measured map
   every other retreat was blocked and the way home failed), but a way in *through* the object
   (a reach onto a pipe's top from above it) goes far deeper and is still refused; the clearance is
   ``end_clearance_m`` beyond the margin at the end. A named simplification of "clearance
   grows along the retreat": it may dip on the way (the way back along the approach passes a
   valve ring's edge: the planner left the ring out around the target, so the approach came
   in through it), never into the object; the motion ends at the first step beyond
   ``min_distance_m`` where the whole robot is collision-free with the planning margin and the
   retreating shapes have ``end_clearance_m`` beyond it.

The result is a joint path (waypoints) that the planner puts before the normal plan; the
executor follows it like any other part (it leaves the voxels around the hand's start out
of its own map, as it always did for a motion starting at the object it reached).
No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel
from humanoid_reach_ros.robot.shapes import CollisionModel

ARM_LIMBS = {"right": "right_arm", "left": "left_arm"}


@dataclass(frozen=True)
class RetreatParams:
    """Contact and retreat thresholds [m] (module doc)."""

    contact_distance_m: float = 0.05
    contact_radius_m: float = 0.15      # = the executor's target_exclusion_radius_m: the object it let the hand into
    min_distance_m: float = 0.05
    max_distance_m: float = 0.25
    step_m: float = 0.01
    end_clearance_m: float = 0.02
    clearance_tolerance_m: float = 0.002
    way_back_depth_m: float = 0.015     # back along the approach: this much deeper than at the start, at most
    damping: float = 1e-3
    iterations: int = 6
    orientation_weight: float = 0.3     # the hand's orientation kept where the arm can, the line first

    def __post_init__(self) -> None:
        for name in ("contact_distance_m", "contact_radius_m", "min_distance_m", "max_distance_m", "step_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"RetreatParams.{name} must be finite and > 0, got {v}")
        if self.min_distance_m > self.max_distance_m:
            raise ValueError("RetreatParams.min_distance_m must be <= max_distance_m")


@dataclass(frozen=True, eq=False)
class Contact:
    """The start touches the map with ``arm``'s hand: its shapes ``shapes`` (names), the hand
    frame at ``hand_p``, the contact point ``point`` (nearest voxel centre), the outward
    ``normal`` (unit) and the voxels within ``contact_radius_m`` of the hand."""

    arm: str
    shapes: tuple[str, ...]
    hand_p: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    voxels: np.ndarray
    distance_m: float

    def describe(self) -> str:
        return (f"the {self.arm} hand ({', '.join(self.shapes)}) touches the map at "
                f"{np.round(self.point, 3).tolist()} m ({1e3 * self.distance_m:.0f} mm)")


@dataclass(frozen=True, eq=False)
class StartCollision:
    """Shapes that collide at the start and are not a hand in contact: names and, per shape,
    the nearest voxel centre [m] and the signed distance [m]."""

    shapes: tuple[str, ...]
    nearest: tuple[np.ndarray, ...]
    distances: tuple[float, ...]

    def describe(self) -> str:
        return "; ".join(f"{n} {1e3 * d:.0f} mm from the voxel at {np.round(p, 3).tolist()} m"
                         for n, p, d in zip(self.shapes, self.nearest, self.distances))


@dataclass(frozen=True, eq=False)
class Retreat:
    """A retreat: joint waypoints (K, n) from the start, its direction and length."""

    joints: np.ndarray
    direction: np.ndarray
    distance_m: float
    label: str
    clearance_m: float

    def describe(self) -> str:
        return (f"retreat {1e3 * self.distance_m:.0f} mm {self.label} (direction "
                f"{np.round(self.direction, 2).tolist()}), clearance at its end {1e3 * self.clearance_m:.0f} mm")


def hand_shape_mask(robot: RobotModel, cm: CollisionModel, arm: str) -> np.ndarray:
    """(S,) bool: the shapes below the elbow (forearm, wrist, hand): those the arm's joints from
    the fourth on move (HRP-2's elbow is its fourth joint, Talos's too). The forearm belongs to
    the contact: a hand at a valve's centre puts its forearm through the ring's plane (measured
    after ``make demo``'s reach: HRP-2's forearm 9 mm into the valve's voxels, its hand 28 mm)."""
    m = robot.model
    spec = robot.limbs[ARM_LIMBS[arm]]
    elbow = m.getJointId(spec.joints[3])
    sub = set(m.subtrees[elbow])
    link_joint = [m.frames[int(f)].parentJoint for f in cm.frame_ids]
    return np.array([link_joint[int(cm.shape_link[s])] in sub for s in range(cm.n_shapes)])


class RetreatPlanner:
    """Contact detection and retreat (module doc) for one robot and collision model."""

    def __init__(self, robot: RobotModel, cm: CollisionModel, params: RetreatParams = RetreatParams()) -> None:
        self.robot = robot
        self.cm = cm
        self.params = params
        self.hand = {arm: hand_shape_mask(robot, cm, arm) for arm in ARM_LIMBS}
        self._self_margin: float | None = None          # of the plan in progress (``plan``)
        self._start_close: set[tuple[str, str]] = set()  # its start's pairs within that margin
        self._data = robot.model.createData()
        self._fid = {arm: robot.model.getFrameId(robot.limbs[limb].tip) for arm, limb in ARM_LIMBS.items()}
        # the arm's joints and the chest's: the chest moves the shoulder when the arm alone is at a
        # limit (Talos at the plant valve: 1 of 8 reaches had no arm-only line out)
        chest = [robot.joint_index[n] for n in robot.spec.chest_joints]
        self._cols = {(arm, with_chest): np.array(list(robot.limbs[limb].joint_index) + (chest if with_chest else []))
                      for arm, limb in ARM_LIMBS.items() for with_chest in (False, True)}

    # ------------------------------------------------------------ contact
    def classify_start(self, q: np.ndarray, tree: SphereTree, margin_m: float,
                       contact_distance_m: float | None = None) -> tuple[Contact | None, StartCollision | None]:
        """``(contact, collision)`` at the start ``q`` against ``tree`` (voxel spheres grown by
        ``margin_m``): a hand in contact (None if none), and the other shapes that collide
        (None if none). Shapes are compared with the map at zero margin for collisions and at
        ``contact_distance_m`` (default the parameter's) for the contact: the planner asks again
        with ``contact_radius_m`` when the start is clear but its way onto the planning manifold
        is not."""
        reach = self.params.contact_distance_m if contact_distance_m is None else float(contact_distance_m)
        if tree.n_spheres == 0:
            return None, None
        P0, P1, R = self.cm.world_shapes(q)
        dist, idx = tree.nearest_batch(P0, P1, R)
        dist = dist + margin_m       # signed distance to the voxels themselves (without the margin)
        names = self.cm.names
        hand_any = self.hand["right"] | self.hand["left"]
        bad = np.flatnonzero((dist < 0) & ~hand_any)
        collision = None
        if bad.size:
            collision = StartCollision(tuple(names[s] for s in bad),
                                       tuple(self._sphere_centre(tree, int(idx[s])) for s in bad),
                                       tuple(float(dist[s]) for s in bad))
        best = None
        for arm in ARM_LIMBS:
            hs = np.flatnonzero(self.hand[arm])
            if not hs.size:
                continue
            d = float(np.min(dist[hs]))
            if d < reach and (best is None or d < best[1]):
                best = (arm, d)
        contact = None if best is None else self._contact(q, tree, best[0], P0, P1, R, dist, idx, reach)
        return contact, collision

    @staticmethod
    def _sphere_centre(tree: SphereTree, i: int) -> np.ndarray:
        return np.asarray(tree.centers[i], float).copy()

    def _contact(self, q, tree, arm, P0, P1, R, dist, idx, reach: float) -> Contact:
        hs = np.flatnonzero(self.hand[arm])
        near = hs[dist[hs] < reach]
        k = near[int(np.argmin(dist[near]))]
        point = self._sphere_centre(tree, int(idx[k]))
        hand_p = self.robot.frame_pose(q, self.robot.limbs[ARM_LIMBS[arm]].tip).translation.copy()
        C = np.asarray(tree.centers, float)
        voxels = C[np.linalg.norm(C - hand_p, axis=1) <= self.params.contact_radius_m]
        centroid = voxels.mean(axis=0) if len(voxels) else point
        n = hand_p - centroid
        if np.linalg.norm(n) < 1e-6:
            n = hand_p - point
        if np.linalg.norm(n) < 1e-6:
            n = np.array([-1.0, 0.0, 0.0])
        return Contact(arm, tuple(self.cm.names[s] for s in near), hand_p, point, n / np.linalg.norm(n), voxels,
                       float(dist[k]))

    # ------------------------------------------------------------ retreat
    def directions(self, q: np.ndarray, contact: Contact, approach: np.ndarray | None = None,
                   ) -> list[tuple[str, np.ndarray]]:
        """Candidate unit directions, in the order they are tried (module doc, step 2)."""
        out: list[tuple[str, np.ndarray]] = []
        if approach is not None and np.linalg.norm(approach) > 1e-6:
            out.append(("against the approach", -np.asarray(approach, float) / np.linalg.norm(approach)))
        n = contact.normal
        out.append(("along the contact normal", n))
        up = n + np.array([0.0, 0.0, 0.7])
        out.append(("along the normal, upward", up / np.linalg.norm(up)))
        shoulder = self.robot.frame_pose(q, self.robot.limbs[ARM_LIMBS[contact.arm]].root).translation
        back = shoulder - contact.hand_p
        if np.linalg.norm(back) > 1e-6:
            out.append(("toward the shoulder", back / np.linalg.norm(back)))
        back_h = np.array([-1.0, 0.0, 0.3]) / math.hypot(1.0, 0.3)
        out.append(("backward and up", back_h))
        # a fan around the normal (30 and 60 deg off it, 6 azimuths): a stretched arm cannot move
        # its hand along itself at first order (measured: 1 of 20 plant valve reaches, every
        # direction above failed at the first step), a tilted line it can
        a = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        for tilt in (math.radians(30), math.radians(60)):
            for k in range(6):
                phi = 2 * math.pi * k / 6
                d = math.cos(tilt) * n + math.sin(tilt) * (math.cos(phi) * a + math.sin(phi) * b)
                out.append((f"{math.degrees(tilt):.0f} deg off the normal", d / np.linalg.norm(d)))
        return out

    def plan(self, joints: np.ndarray, contact: Contact, tree: SphereTree, margin_m: float,
             approach: np.ndarray | None = None, reverse_path: np.ndarray | None = None,
             min_distance_m: float | None = None, self_margin_m: float | None = None,
             ) -> tuple[Retreat | None, list[str]]:
        """The first retreat that passes every check (module doc) and the reasons the others
        failed. ``reverse_path`` (K, n): the last plan's samples backwards from where the robot
        stands (the way the hand came in), tried first; then the Cartesian directions.
        ``min_distance_m``: a longer retreat than the parameter's (at most ``max_distance_m``).
        ``self_margin_m``: the planner's self-collision margin; a retreat posture whose shapes
        come closer to each other than it (pairs not that close at the start) is refused (None:
        not checked). bench/session s15: a chest-home retreat ended with the other forearm in
        the waist, and the planner refused its end."""
        self._self_margin = self_margin_m
        saved = self.params
        if min_distance_m is not None:
            self.params = replace(saved, min_distance_m=min(max(float(min_distance_m), saved.min_distance_m),
                                                            saved.max_distance_m))
        try:
            return self._plan(joints, contact, tree, margin_m, approach, reverse_path)
        finally:
            self.params = saved

    def _plan(self, joints, contact, tree, margin_m, approach, reverse_path) -> tuple[Retreat | None, list[str]]:
        q0 = self.robot.config(joints, self.robot.base_on_feet(joints))
        self._start_close = self._close_pairs(*self.cm.world_shapes(q0)[:2])
        allowed = (SphereTree.from_voxels(contact.voxels, 2.0 * (float(tree.radii[0]) - margin_m))
                   if len(contact.voxels) else None)
        reasons = []
        if reverse_path is not None and len(reverse_path) > 1:
            r, why = self._back_along(q0, contact, np.asarray(reverse_path, float), tree, margin_m, allowed)
            if r is not None:
                return r, reasons
            reasons.append(f"back along the approach: {why}")
        # the arm alone first: a chest the retreat bends is bent back by the plan's pre-segment (to
        # the reference), which swings the hand back (seen: chest pitch 0.06 -> 0.60 rad, the hand
        # into the valve at 50 % of the pre-segment); the chest only where the arm alone cannot
        # (first, the chest returns to its reference over the retreat, the arm keeping the line)
        candidates = [(mode, label, d) for mode in ("chest home", "arm", "arm and chest")
                      for label, d in self.directions(q0, contact, approach)]
        for mode, label, d in candidates:
            label = f"{label}, {mode}"
            r, why = self._along(q0, contact, d, label, tree, margin_m, allowed, mode)
            if r is not None:
                return r, reasons
            reasons.append(f"{label}: {why}")
        return None, reasons

    def _along(self, q0, contact, d, label, tree, margin_m, allowed, mode: str = "arm",
               ) -> tuple[Retreat | None, str]:
        """The hand on the line ``p_0 + s d``. ``mode``: ``arm`` (the arm's joints follow it),
        ``arm and chest`` (the chest's too), ``chest home`` (the chest moves to its reference
        linearly over ``min_distance_m`` while the arm follows the line)."""
        p = self.params
        arm = contact.arm
        fid, cols = self._fid[arm], self._cols[(arm, mode == "arm and chest")]
        chest_q = np.array([self.robot.joint_index[n] for n in self.robot.spec.chest_joints]) + N_BASE_Q
        chest_0 = q0[chest_q].copy()
        chest_ref = self.robot.half_sitting_joints[chest_q - N_BASE_Q]
        if mode == "chest home" and np.max(np.abs(chest_ref - chest_0)) < 1e-6:
            return None, "the chest is at its reference already"
        vcols = cols + N_BASE_V
        qcols = cols + N_BASE_Q
        model, data = self.robot.model, self._data
        pin.framesForwardKinematics(model, data, q0)
        M0 = data.oMf[fid].copy()
        lo, hi = self.robot.lower[cols], self.robot.upper[cols]
        hand = self.hand[arm]
        q = q0.copy()
        path = [q0[N_BASE_Q:].copy()]
        prev_clear = self._hand_clearance(q0, allowed, hand)
        n_steps = int(math.ceil(p.max_distance_m / p.step_m))
        for k in range(1, n_steps + 1):
            s = min(k * p.step_m, p.max_distance_m)
            target = pin.SE3(M0.rotation, M0.translation + s * d)
            if mode == "chest home":
                q[chest_q] = chest_0 + min(1.0, s / p.min_distance_m) * (chest_ref - chest_0)
            # the first step may start singular (a stretched arm); a step that has not reached the line
            # within its iterations gets up to three more rounds before the line counts as lost
            # (damped least squares converges slowly near a singularity)
            budget = p.iterations * (4 if k == 1 else 1)
            for it in range(budget + 3 * p.iterations):
                pin.framesForwardKinematics(model, data, q)
                M = data.oMf[fid]
                err = np.concatenate([target.translation - M.translation,
                                      p.orientation_weight * pin.log3(M0.rotation @ M.rotation.T)])
                line = np.linalg.norm(err[:3])
                if line < 1e-6 or (it >= budget and line <= 2e-3):
                    break
                J = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:, vcols]
                J[3:] *= p.orientation_weight
                dq = J.T @ np.linalg.solve(J @ J.T + p.damping * np.eye(6), err)
                q[qcols] = np.clip(q[qcols] + dq, lo, hi)   # the limits hold; the line may then be lost
            pin.framesForwardKinematics(model, data, q)
            if np.linalg.norm(data.oMf[fid].translation - target.translation) > 2e-3:
                return None, f"the arm cannot follow the line beyond {1e3 * (s - p.step_m):.0f} mm (IK, limits)"
            why, dist, _ = self._step_ok(q, contact, tree, margin_m, allowed, prev_clear, f"at {1e3 * s:.0f} mm")
            if why:
                return None, why
            path.append(q[N_BASE_Q:].copy())
            arm_clear = float(np.min(dist[hand])) - margin_m   # the retreating shapes, with the planning margin
            if s >= p.min_distance_m - 1e-9 and arm_clear >= p.end_clearance_m and np.all(dist >= margin_m) \
                    and (mode != "chest home" or np.max(np.abs(q[chest_q] - chest_ref)) < 1e-9):
                return Retreat(np.array(path), d, s, label, arm_clear), ""
        return None, f"no clearance of {1e3 * p.end_clearance_m:.0f} mm within {1e3 * p.max_distance_m:.0f} mm"

    def _step_ok(self, q, contact, tree, margin_m, allowed, prev_clear, where: str,
                 way_in: bool = False) -> tuple[str, np.ndarray, float]:
        """The checks of one retreat posture (module doc, step 4): ``(why not or '', dist, clearance)``;
        ``way_in``: a sample of the way the hand came in (:meth:`_back_along`), which may go
        ``way_back_depth_m`` deeper into the contact's voxels than the start."""
        hand, other = self.hand[contact.arm], ~self.hand[contact.arm]
        P0, P1, R = self.cm.world_shapes(q)
        dist = tree.nearest_batch(P0, P1, R)[0] + margin_m
        if np.any(dist[other] < 0):
            names = [self.cm.names[i] for i in np.flatnonzero(other & (dist < 0))]
            return f"{', '.join(names)} would touch the map {where}", dist, prev_clear
        if (pairs := self._new_self_contacts(P0, P1)):
            return f"{pairs} would come within the self-collision margin {where}", dist, prev_clear
        clear = self._hand_clearance(q, allowed, hand)
        depth = self.params.way_back_depth_m if way_in else self.params.clearance_tolerance_m
        if clear < min(prev_clear, 0.0) - depth:
            return f"the hand would press into the contact's voxels {where}", dist, prev_clear
        if np.any(dist[hand] < 0) and self._outside_contact(P0, P1, R, hand, tree, margin_m, contact):
            return f"the hand would touch voxels away from the contact {where}", dist, prev_clear
        return "", dist, prev_clear

    def _close_pairs(self, P0: np.ndarray, P1: np.ndarray) -> set[tuple[str, str]]:
        """The shape pairs closer than the plan's self-collision margin (none when unchecked)."""
        if self._self_margin is None:
            return set()
        return {(a, b) for a, b, _ in self.cm.colliding_pairs(P0, P1, margin=self._self_margin)}

    def _new_self_contacts(self, P0: np.ndarray, P1: np.ndarray) -> str:
        """``"a<->b, ..."``: the pairs closer than the self-collision margin here that were not at
        the start, or ""."""
        return ", ".join(f"{a}<->{b}" for a, b in sorted(self._close_pairs(P0, P1) - self._start_close))

    def _back_along(self, q0, contact, path, tree, margin_m, allowed) -> tuple[Retreat | None, str]:
        """The retreat along ``path`` (joint samples from the start backwards): the first sample
        whose hand is ``min_distance_m`` from the start and has the end clearance ends it."""
        p = self.params
        hand = self.hand[contact.arm]
        tip = self.robot.limbs[ARM_LIMBS[contact.arm]].tip
        p0 = self.robot.frame_pose(q0, tip).translation
        prev = self._hand_clearance(q0, allowed, hand)
        out = [path[0]]
        lo, hi = self.robot.lower - 1e-9, self.robot.upper + 1e-9
        for k in range(1, len(path)):
            j = path[k]
            if np.any(j < lo) or np.any(j > hi):
                return None, f"sample {k} outside the joint limits"
            q = self.robot.config(j, self.robot.base_on_feet(j))
            why, dist, prev = self._step_ok(q, contact, tree, margin_m, allowed, prev, f"at sample {k}", way_in=True)
            if why:
                return None, why
            out.append(j)
            moved = float(np.linalg.norm(self.robot.frame_pose(q, tip).translation - p0))
            arm_clear = float(np.min(dist[hand])) - margin_m
            if moved >= p.min_distance_m and arm_clear >= p.end_clearance_m and np.all(dist >= margin_m):
                d = (self.robot.frame_pose(q, tip).translation - p0) / max(moved, 1e-9)
                return Retreat(np.array(out), d, moved, "back along the approach", arm_clear), ""
            if moved > p.max_distance_m:
                break
        return None, f"no clearance of {1e3 * p.end_clearance_m:.0f} mm within {1e3 * p.max_distance_m:.0f} mm"

    def _hand_clearance(self, q, allowed: SphereTree | None, hand: np.ndarray) -> float:
        if allowed is None or allowed.n_spheres == 0:
            return math.inf
        P0, P1, R = self.cm.world_shapes(q)
        return float(np.min(allowed.nearest_batch(P0[hand], P1[hand], R[hand])[0]))

    def _outside_contact(self, P0, P1, R, hand, tree, margin_m, contact) -> bool:
        hs = np.flatnonzero(hand)
        for s in hs:
            idx, dd = tree.spheres_within(P0[s], P1[s], R[s], 0.0)
            for i in idx[dd < -1e-9]:
                c = self._sphere_centre(tree, int(i))
                if np.linalg.norm(c - contact.hand_p) > self.params.contact_radius_m:
                    return True
        return False


__all__ = ["RetreatParams", "Contact", "StartCollision", "Retreat", "RetreatPlanner", "hand_shape_mask"]
