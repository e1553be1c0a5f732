"""Whole-body gaze: the chest and head joints that aim the head camera at a point.

The executor's ``/look`` at ``gaze_points`` (``execution/requests.py``) and the planner's
``UNOBSERVABLE_SPACE`` answer ask the same question: which chest yaw/pitch and head
yaw/pitch (``robot.spec.chest_joints``, ``robot.spec.neck_joints``) turn the camera's optical
axis onto a world point, and does the camera then see it? Everything else stays: the arms,
and the legs, so the waist (:meth:`RobotModel.base_on_feet`, feet fixed) -- except in the
executor's balanced gaze, whose legs keep the COG (*Balance* below).

**Tiers.** The gaze joints are two tiers in this order: the chest (yaw, pitch) and the neck
(yaw, pitch), whose joints the robot description gives by role. A robot without a neck
(``robot.spec.has_neck`` False: its description's head names the camera frame only) has the
chest tier alone, and its head stays where it is (*Without a neck* below). Simplification: a
chest roll (``chest.roll`` of the description, ``robot.spec.torso_joints``) is not a gaze
joint: it keeps its value in the input joints, like the arms. Yaw and pitch alone turn the
optical axis in both its directions; a roll would widen the directions within reach by
leaning the body sideways (and moving the COG), which this solver does not search.

**Aiming.** The optical frame (``robot.spec.camera_frame``) looks along its +z (REP 103 /
OpenCV: z forward, x right, y down; ``geometry/camera.py``, ``sim/camera.py`` and the
marker localizer use the frame so). With ``a`` the optical axis, ``c`` the camera's position
and ``d = (p - c) / |p - c|`` the unit ray to the point, the residual is ``r = a - d``
(zero exactly when aimed; ``|r| = 2 sin(alpha / 2)``, ``alpha`` the off-axis angle), and its
Jacobian in the gaze joints (4 with a neck, 2 without) is

    J_r = -[a]x J_w + (I - d d^T) J_v / |p - c|

(``J_w``, ``J_v``: the camera frame's angular and linear Jacobian columns of the gaze joints,
world axes; the second term: the camera moves, so the ray to the point turns). A damped
Gauss-Newton step ``dx = -W J^T (J W J^T + lambda I)^-1 r``, clipped to the joint limits (a
joint at a limit that the step pushes further out leaves ``W``), repeats until ``alpha`` is
below ``aim_tol_rad``, starting from the point's yaw and pitch seen with the head joints at
zero. The head is preferred, the chest moved only where the head cannot aim, and then as
little as it can:

1. the head alone, the chest where it is (a point in front: head only);
2. if the head cannot aim, the head alone again at each chest posture of a grid over the
   chest's limits (``chest_grid``, 9 x 7), nearest the current chest first, until one aims;
3. from there, the chest posture nearest the current one that still lets the head aim: along
   the ray of chest postures towards it the least distance that aims (bisection), the ray's
   direction refined by a golden-section search. The grid, not a descent from the start, is
   what finds it: a Gauss-Newton on all 4 joints from the start ended in local minima (Talos,
   point beside the hip: 41 deg off where a gaze 4.3 deg off exists). On 150 random reachable
   gazes per robot (random chest and head in their limits, a point 0.4-3 m along the axis)
   every point is aimed (< 0.05 deg) and the chest moves at most 0.007 rad more than in the
   gaze that made the point;
4. if no chest posture lets the head aim (a point behind the robot), the best effort: the
   nearest miss of the grid, polished by Gauss-Newton on all 4 joints.

**Without a neck** the chest aims the camera: two joints for the axis's two directions, so
the aimed postures are isolated points, not a set to search for the nearest. The same steps
with the chest's Gauss-Newton in the head's place: (1) from the current chest; (2) if that
does not aim, from each posture of the chest grid, nearest the current chest first, until
one aims (that gaze is taken: simplification, another start might converge on an aimed
posture nearer the current one); (3) none aims: the best effort, the nearest miss polished
as in 4. HRP-2 without its neck (test_gaze.py), 150 random reachable gazes from half-sitting
and 300 from random chest postures: step 1 aimed every one (< 0.001 deg) with the chest moved
no more than in the posture that made the point; the grid served only the points out of
reach (behind, beside, low: 26-150 ms for its 63 solves). It is there for what step 1 cannot: the
residual ``a - d`` is stationary with the axis turned away from the point, which a chest
yawing further than HRP-2's 45 deg can start from.

HRP-2 at half-sitting, point [0.25, -0.29, 0.66] m beside the right hip: the head saturates
at 45 deg down and the chest turns by 0.74 rad (yaw -19, pitch 38 deg); a brute-force grid of
25 x 25 chest postures finds 0.743 rad.

**Balance** (:meth:`GazeSolver.balanced`, what the executor's ``/look`` follows). The executor
keeps the feet and the exact COG (level 2) above the hand (level 3) and the posture (level 4,
which carries the gaze). A chest leaning 38 deg moves the COG forward, the legs move the waist
back (25 mm) and the hand held at level 3 then pulls the posture away from the reference: the
chest's yaw ended 3-4 deg off and the camera 2.2 deg (HRP-2) to 3.3 deg (Talos) off the hip
point. So the executor's gaze is balanced beforehand: the lower-body IK of Algorithm 3
(``dual_arm/lower_body_ik.py``) puts the COG back over the same point with the feet and the
waist's orientation fixed, the gaze is aimed again from the moved waist, and so on until the
legs stop moving (2-4 rounds); the reference is then consistent with every level and the
executor follows it (hip point: 0.13 deg off at the end on HRP-2, test_gaze.py).

**Seeing.** A gaze sees a point when the point is within the camera's field of view and its
range: the angle between the optical axis and the ray is at most the half-angle of the cone
inscribed in the image (``GazeCamera.half_fov_rad``: ``atan(min(W / (2 fx), H / (2 fy)))``,
23.4 deg for the 640 x 480, 60 deg camera of ``config/scene_sim.yaml``; the cone does not depend
on the camera's roll about its axis, which the gaze joints do not control), and its distance
between the depth sensor's minimum range and the voxel mapper's ``max_range_m`` (rays are
truncated there: space beyond is never observed). :meth:`GazeSolver.observable` asks whether
some reachable gaze sees each point; :meth:`GazeSolver.best_gaze` aims at a set's centroid.

Simplifications: the robot's own body is not an occluder (a point seen "through" the arm or
the chest counts as seen), neither is the environment (a point behind a wall counts as seen);
the voxel mapper's box (``extent_min_m`` / ``extent_max_m``) is not a limit here (the caller's
points are expected inside it);
collisions of the gaze posture are left to the executor's dampers; the camera's intrinsics are
the defaults of ``config/scene_sim.yaml`` unless a :class:`GazeCamera` is given; the field of
view is the inscribed cone, so a point in an image corner outside it counts as unseen;
:meth:`observable` and :meth:`best_gaze` use the kinematic gaze (the balanced one moves the
camera by the waist's few centimetres).

No ROS here.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.geometry.camera import PinholeCamera
from humanoid_reach_ros.perception.voxel_map import FusionParams
from humanoid_reach_ros.robot.model import N_BASE_Q, N_BASE_V, RobotModel

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
#: the chest tier: yaw, pitch, the first gaze joints (the neck's, where there is one, follow)
_N_CHEST = 2

#: the head camera of config/scene_sim.yaml (width, height [px], horizontal field of view [rad])
DEFAULT_IMAGE = (640, 480, math.radians(60.0))
#: the depth sensor's minimum range of config/scene_sim.yaml [m]
DEFAULT_MIN_RANGE_M = 0.1


def _default_camera() -> PinholeCamera:
    return PinholeCamera.from_fov(*DEFAULT_IMAGE)


@dataclass(frozen=True)
class GazeCamera:
    """What the head camera sees: its intrinsics and the range in which a point counts as
    observed (``max_range_m``: the voxel mapper's ray truncation, ``FusionParams``)."""

    camera: PinholeCamera = field(default_factory=_default_camera)
    min_range_m: float = DEFAULT_MIN_RANGE_M
    max_range_m: float = FusionParams.max_range_m

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_range_m) and math.isfinite(self.max_range_m)
                and 0.0 <= self.min_range_m < self.max_range_m):
            raise ValueError(f"ranges must be finite with 0 <= min_range_m < max_range_m, got "
                             f"{self.min_range_m}, {self.max_range_m}")

    @property
    def half_fov_rad(self) -> float:
        """Half-angle of the cone inscribed in the image: ``atan(min(W / (2 fx), H / (2 fy)))``."""
        c = self.camera
        return math.atan(min(0.5 * c.width / c.fx, 0.5 * c.height / c.fy))


@dataclass(frozen=True)
class GazeParams:
    """Solver settings (units in the names)."""

    aim_tol_rad: float = 1e-5           # aimed: off-axis angle below this
    max_iter: int = 40                  # Gauss-Newton steps per solve
    max_step_rad: float = 0.4           # largest joint step of one iteration (the linearisation's range)
    damping: float = 1e-6               # lambda of the damped step
    chest_weight: float = 0.3           # the chest's steps cost 1 / chest_weight^2 as much as the head's
    aimed_tol_rad: float = math.radians(0.05)   # a gaze this close counts as aimed (the chest searches below)
    chest_grid: tuple[int, int] = (9, 7)        # chest postures searched: yaw x pitch points over the limits
    bisection_steps: int = 6            # along a ray of chest postures: the least distance that aims
    golden_steps: int = 6               # the ray's direction refined within +- refine_angle_rad
    refine_angle_rad: float = 0.35
    balance_iterations: int = 6         # balanced(): aim, balance, aim again ... at most this often
    balance_tol_rad: float = 1e-4       # ... until the legs move less than this
    balance_max_iter: int = 50          # lower-body IK iterations


@dataclass(frozen=True, eq=False)
class Gaze:
    """One gaze: the joints (the input with the chest and head joints changed; with
    ``balanced``, the legs too: :meth:`GazeSolver.balanced`), the point, the camera's position
    and optical axis (world, standing on the feet), the angle between that axis and the ray to
    the point, the range, whether the camera sees it (:class:`GazeCamera`), the field of view's
    half-angle and how far the chest moved (the norm of its 2 joints' changes)."""

    joints: np.ndarray
    point: np.ndarray
    camera_position: np.ndarray
    camera_axis: np.ndarray
    off_axis_rad: float
    range_m: float
    visible: bool
    half_fov_rad: float
    chest_moved_rad: float
    balanced: bool = False
    range_limits_m: tuple[float, float] = (0.0, math.inf)
    #: why the motion stops short of this gaze ("" when it goes all the way): the executor's
    #: look keeps its clearance (``ExecutionRequests.gaze``); ``joints`` are then where it stops
    held_back: str = ""

    @property
    def off_axis_deg(self) -> float:
        return math.degrees(self.off_axis_rad)

    @property
    def unseen_reason(self) -> str:
        """Why the camera does not see the point ("" when it does)."""
        if self.visible:
            return ""
        if self.held_back:
            return f"not in view ({self.held_back})"
        if self.off_axis_rad > self.half_fov_rad:
            return (f"not in view ({self.off_axis_deg:.1f} deg off the camera axis, half field of view "
                    f"{math.degrees(self.half_fov_rad):.1f} deg)")
        lo, hi = self.range_limits_m
        return f"not in view ({self.range_m:.2f} m away, the camera sees {lo:g}-{hi:g} m)"


@dataclass(frozen=True, eq=False)
class GazeSet:
    """The gaze at a set of points' centroid and, per point, the off-axis angle, the range and
    whether that gaze sees it."""

    gaze: Gaze
    points: np.ndarray
    off_axis_rad: np.ndarray
    range_m: np.ndarray
    in_view: np.ndarray


class GazeSolver:
    """Chest and head joints that aim the head camera at a point (module doc); the chest
    alone for a robot without a neck (``robot.spec.has_neck`` False).

    Has its own pinocchio data: one solver per thread, or calls serialised."""

    def __init__(self, robot: RobotModel, camera: GazeCamera | None = None,
                 params: GazeParams = GazeParams()) -> None:
        self.robot = robot
        self.camera = GazeCamera() if camera is None else camera
        self.params = params
        self.model = robot.model
        self.data = self.model.createData()
        spec = robot.spec
        #: whether the head turns on a neck; without, the chest tier aims the camera alone
        self.has_neck = spec.has_neck
        #: the gaze joints: chest yaw, chest pitch, then head yaw, head pitch where there is a neck
        self.names: tuple[str, ...] = (*spec.chest_joints, *spec.neck_joints)
        #: their indices in the joint vector
        self.index = np.array([robot.joint_index[n] for n in self.names], dtype=np.intp)
        self._cols = N_BASE_V + self.index      # every joint of the description has one DOF
        self.lower, self.upper = robot.lower[self.index], robot.upper[self.index]
        self._cam_id = robot.frame_id(robot.camera_frame)
        self._sole_id = robot.frame_id(robot.sole_frames[0])
        n_neck = len(spec.neck_joints)
        self._w = np.concatenate([np.full(_N_CHEST, params.chest_weight), np.ones(n_neck)]) ** 2
        #: free joints of a solve (1) and held ones (0): the neck alone, every gaze joint
        self._neck_only = np.concatenate([np.zeros(_N_CHEST), np.ones(n_neck)])
        self._all = np.ones(len(self.names))
        self._legs = None       # the lower-body IK of balanced(), built on first use

    # ------------------------------------------------------------ validation
    def _joints(self, joints) -> np.ndarray:
        j = np.array(joints, dtype=float)
        if j.shape != (self.robot.n_joints,):
            raise ValueError(f"joints must have shape ({self.robot.n_joints},), got {j.shape}")
        if not np.all(np.isfinite(j)):
            raise ValueError("joints contain NaN or inf")
        return j

    @staticmethod
    def _points(points) -> np.ndarray:
        P = np.array(points, dtype=float)
        if P.ndim == 1:
            P = P[None]
        if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
            raise ValueError(f"points must have shape (3,) or (N, 3) with N >= 1, got {np.shape(points)}")
        if not np.all(np.isfinite(P)):
            raise ValueError("points contain NaN or inf")
        return P

    # ------------------------------------------------------------ kinematics
    def _base(self, joints: np.ndarray) -> pin.SE3:
        """:meth:`RobotModel.base_on_feet` on this solver's data: the waist that puts the right sole
        at its stance pose (the chest and head do not move it; the legs of :meth:`balanced` do)."""
        pin.framesForwardKinematics(self.model, self.data, self.robot.config(joints))
        return self.robot.stance_soles[0] * self.data.oMf[self._sole_id].inverse()

    def _camera(self, q: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Camera position, optical axis (+z) and, with ``jacobian``, the frame's world-axes
        Jacobian (6 x gaze joints) of the gaze joints."""
        if jacobian:
            J = pin.computeFrameJacobian(self.model, self.data, q, self._cam_id, LWA)[:, self._cols]
            pin.updateFramePlacement(self.model, self.data, self._cam_id)
        else:
            pin.framesForwardKinematics(self.model, self.data, q)
            J = None
        M = self.data.oMf[self._cam_id]
        return M.translation.copy(), M.rotation[:, 2].copy(), J

    # ------------------------------------------------------------ aiming
    def _aim(self, q: np.ndarray, point: np.ndarray, x: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, float]:
        """Gauss-Newton from ``x`` (the gaze joints) on the ``free`` ones (module doc); returns the
        joints and the off-axis angle."""
        p = self.params
        idx = self.index
        x = np.clip(x, self.lower, self.upper)
        best_x, best_alpha = x.copy(), math.inf
        for _ in range(p.max_iter + 1):
            q[N_BASE_Q + idx] = x
            c, a, J = self._camera(q, True)
            v = point - c
            rho = max(float(np.linalg.norm(v)), 1e-9)
            d = v / rho
            alpha = math.acos(min(1.0, max(-1.0, float(a @ d))))
            if alpha < best_alpha:
                best_x, best_alpha = x.copy(), alpha
            if alpha <= p.aim_tol_rad:
                break
            r = a - d
            skew_a = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            Jr = -skew_a @ J[3:] + (np.eye(3) - np.outer(d, d)) @ J[:3] / rho
            W = self._w * free
            at_low, at_high = x <= self.lower + 1e-12, x >= self.upper - 1e-12
            for _ in range(4):   # a joint at a limit that the step pushes further out leaves W
                JW = Jr * W
                step = -JW.T @ np.linalg.solve(JW @ Jr.T + p.damping * np.eye(3), r)
                out = ((at_low & (step < 0.0)) | (at_high & (step > 0.0))) & (W > 0.0)
                if not out.any():
                    break
                W = np.where(out, 0.0, W)
            n = float(np.max(np.abs(step)))
            if n > p.max_step_rad:
                step *= p.max_step_rad / n
            x_new = np.clip(x + step, self.lower, self.upper)
            if np.max(np.abs(x_new - x)) < 1e-10:    # stuck at the limits: best effort
                break
            x = x_new
        q[N_BASE_Q + idx] = best_x
        return best_x, best_alpha

    def _head_guess(self, q: np.ndarray, point: np.ndarray, chest: np.ndarray) -> np.ndarray:
        """The gaze joints with ``chest`` and the head at the point's yaw (left > 0) and pitch
        (down > 0) seen by the camera with the head joints at zero, clipped into the head's limits
        (exact for a camera at the head joints' intersection; the start of the head's solve).
        Only with a neck."""
        x = np.concatenate([chest, np.zeros(len(self.names) - _N_CHEST)])
        q[N_BASE_Q + self.index] = x
        pin.framesForwardKinematics(self.model, self.data, q)
        M = self.data.oMf[self._cam_id]
        d = M.rotation.T @ (point - M.translation)          # optical frame: z forward, x right, y down
        x[_N_CHEST:] = np.clip([math.atan2(-d[0], d[2]), math.atan2(d[1], math.hypot(d[0], d[2]))],
                               self.lower[_N_CHEST:], self.upper[_N_CHEST:])
        return x

    def _head_aim(self, q: np.ndarray, point: np.ndarray, chest: np.ndarray) -> tuple[np.ndarray, float]:
        """The head alone aims, the chest at ``chest``: (gaze joints, off-axis angle). Only with a neck."""
        return self._aim(q, point, self._head_guess(q, point, chest), self._neck_only)

    def _aim_from(self, q: np.ndarray, point: np.ndarray, chest: np.ndarray) -> tuple[np.ndarray, float]:
        """The solve of one chest posture of the search: with a neck, the head alone aims with the
        chest at ``chest`` (:meth:`_head_aim`); without, the chest aims, starting at ``chest``."""
        if self.has_neck:
            return self._head_aim(q, point, chest)
        return self._aim(q, point, np.array(chest, dtype=float), self._all)

    def _chest_grid(self) -> np.ndarray:
        """Chest postures (K, 2) over the chest's limits (``chest_grid`` points a joint)."""
        ny, npitch = self.params.chest_grid
        yaw = np.linspace(self.lower[0], self.upper[0], ny)
        pitch = np.linspace(self.lower[1], self.upper[1], npitch)
        return np.stack(np.meshgrid(yaw, pitch, indexing="ij"), -1).reshape(-1, 2)

    def _least_chest(self, q: np.ndarray, point: np.ndarray, chest0: np.ndarray,
                     found: tuple[np.ndarray, float]) -> tuple[np.ndarray, float]:
        """From an aimed gaze ``found``, the chest posture nearest ``chest0`` from which the head
        still aims: along a ray from ``chest0`` the least distance that aims (bisection), the
        ray's direction refined by a golden-section search within ``refine_angle_rad``."""
        p = self.params
        tol = p.aimed_tol_rad
        best = found
        best_dist = float(np.linalg.norm(found[0][:_N_CHEST] - chest0))

        def radial(phi: float, t_hi: float) -> tuple[float, tuple[np.ndarray, float] | None]:
            nonlocal best, best_dist
            u = np.array([math.cos(phi), math.sin(phi)])
            with np.errstate(divide="ignore", invalid="ignore"):   # the ray's exit from the chest's box
                exits = np.where(u > 0, (self.upper[:_N_CHEST] - chest0) / u,
                                 np.where(u < 0, (self.lower[:_N_CHEST] - chest0) / u, np.inf))
            t_hi = min(t_hi, float(np.min(exits)))
            hi = self._head_aim(q, point, chest0 + t_hi * u)
            if hi[1] > tol:
                return math.inf, None
            t_lo = 0.0
            for _ in range(p.bisection_steps):
                t = 0.5 * (t_lo + t_hi)
                cand = self._head_aim(q, point, chest0 + t * u)
                if cand[1] <= tol:
                    t_hi, hi = t, cand
                else:
                    t_lo = t
            dist = float(np.linalg.norm(hi[0][:_N_CHEST] - chest0))
            if dist < best_dist:
                best, best_dist = hi, dist
            return t_hi, hi

        d0 = found[0][:_N_CHEST] - chest0
        phi0 = math.atan2(d0[1], d0[0])
        reach = 1.5 * best_dist          # farther than the found gaze: never nearer
        radial(phi0, best_dist)
        a, b = phi0 - p.refine_angle_rad, phi0 + p.refine_angle_rad
        g = (math.sqrt(5.0) - 1.0) / 2.0
        c, d = b - g * (b - a), a + g * (b - a)
        fc, fd = radial(c, reach)[0], radial(d, reach)[0]
        for _ in range(p.golden_steps):
            if fc <= fd:
                b, d, fd = d, c, fc
                c = b - g * (b - a)
                fc = radial(c, reach)[0]
            else:
                a, c, fc = c, d, fd
                d = a + g * (b - a)
                fd = radial(d, reach)[0]
        return best

    def _search(self, q: np.ndarray, point: np.ndarray, x0: np.ndarray,
                enough: Callable[[np.ndarray, float], bool]) -> tuple[list[tuple[np.ndarray, float]], bool]:
        """The solve (:meth:`_aim_from`) at the current chest, then at every chest posture of the
        grid (nearest ``x0``'s chest first) until ``enough(x, alpha)``: (the solves, stopped early)."""
        chest0 = x0[:_N_CHEST]
        out = [self._aim_from(q, point, chest0)]
        if enough(*out[0]):
            return out, True
        grid = self._chest_grid()
        for c in grid[np.argsort(np.linalg.norm(grid - chest0, axis=1), kind="stable")]:
            out.append(self._aim_from(q, point, c))
            if enough(*out[-1]):
                return out, True
        return out, False

    def solve(self, joints, point) -> Gaze:
        """The gaze at ``point`` (3,) [m, world] from ``joints`` (n,): head first, the chest
        only where the head cannot aim, and then as little as it can; without a neck, the chest
        from the current posture, else from the grid's (module doc). A point no
        gaze can aim at gets the best effort (the smallest off-axis angle found), ``visible``
        telling whether it is seen. ``ValueError`` on NaN/inf or wrong shapes."""
        j = self._joints(joints)
        P = np.array(point, dtype=float)
        if P.shape != (3,):
            raise ValueError(f"point must have shape (3,), got {P.shape}")
        P = self._points(P)[0]
        base = self._base(j)
        q = self.robot.config(j, base)
        x0 = np.clip(j[self.index], self.lower, self.upper)    # measured joints may be a hair outside
        chest0 = x0[:_N_CHEST]
        tol = self.params.aimed_tol_rad
        # the grid is searched nearest the current chest first: its first aimed posture is the nearest
        solves, aimed = self._search(q, P, x0, lambda x, a: a <= tol)
        if aimed and len(solves) > 1 and self.has_neck:
            x = self._least_chest(q, P, chest0, solves[-1])[0]
        elif aimed:    # without a neck: the chest's aimed posture (isolated: no nearer one along a ray)
            x = solves[-1][0]
        else:   # best effort: the nearest miss, polished with every gaze joint
            x, alpha = min(solves, key=lambda s: s[1])
            x2, alpha2 = self._aim(q, P, x, self._all)
            x = x2 if alpha2 < alpha else x
        out = j.copy()
        out[self.index] = x
        return self._gaze(out, base, P, float(np.linalg.norm(x[:_N_CHEST] - j[self.index[:_N_CHEST]])))

    def _gaze(self, joints: np.ndarray, base: pin.SE3, point: np.ndarray, chest_moved: float,
              balanced: bool = False) -> Gaze:
        c, a, _ = self._camera(self.robot.config(joints, base), False)
        alpha, rng = self._angles(c, a, point[None])
        cam = self.camera
        return Gaze(joints, point.copy(), c, a, float(alpha[0]), float(rng[0]), bool(self._sees(alpha, rng)[0]),
                    cam.half_fov_rad, chest_moved, balanced, (cam.min_range_m, cam.max_range_m))

    def head_reaimed(self, joints, point) -> np.ndarray:
        """``joints`` with the head alone aimed at ``point`` again, the chest and the legs kept: where
        a gaze is held back part of the way (its clearance), the head -- which moves no arm --
        still turns the rest of its way, and the camera's field of view, not its axis, may bring the
        point into view (Talos, the space beside its hanging right hand: the chest's pitch would
        swing the hands into the passage pipe, the head alone at its pitch limit sees it 11 deg off
        the axis). Without a neck: ``joints`` unchanged."""
        j = self._joints(joints)
        if not self.has_neck:
            return j
        P = self._points(np.asarray(point, dtype=float).reshape(1, 3))[0]
        q = self.robot.config(j, self._base(j))
        x, _ = self._head_aim(q, P, np.clip(j[self.index[:_N_CHEST]], self.lower[:_N_CHEST], self.upper[:_N_CHEST]))
        out = j.copy()
        out[self.index[_N_CHEST:]] = x[_N_CHEST:]
        return out

    def stopped_short(self, gaze: Gaze, start, joints, why: str) -> Gaze:
        """``gaze`` (from joints ``start``) stopped at ``joints`` on its way (the executor's look
        keeps its clearance): the camera as it is there, whether it sees the point, and
        ``held_back`` = ``why``."""
        j, j0 = self._joints(joints), self._joints(start)
        chest = self.index[:_N_CHEST]
        g = self._gaze(j, self._base(j), gaze.point, float(np.linalg.norm(j[chest] - j0[chest])), gaze.balanced)
        return dataclasses.replace(g, held_back=why)

    # ------------------------------------------------------------ balance
    def balanced(self, joints, point) -> Gaze:
        """:meth:`solve`, then the legs keep the exact COG where it is (module doc, *Balance*):
        the lower-body IK (``dual_arm/lower_body_ik.py``, Algorithm 3, right sole fixed) puts the
        COG's xy back at that of ``joints`` (its height: the gaze's own), the waist's
        orientation and the left sole where they were; the gaze is solved again from the
        balanced posture, until the legs move less than ``balance_tol_rad``. Where the legs
        cannot (the IK does not converge) the kinematic gaze is returned (``balanced`` False)."""
        j = self._joints(joints)
        P = np.array(point, dtype=float)
        if P.shape != (3,):
            raise ValueError(f"point must have shape (3,), got {P.shape}")
        P = self._points(P)[0]
        from humanoid_reach_ros.dual_arm.lower_body_ik import LegTargets, LowerBodyIK
        if self._legs is None:
            self._legs = LowerBodyIK(self.robot, "right", max_iter=self.params.balance_max_iter)
        base = self._base(j)
        q_in = self.robot.config(j, base)
        pin.framesForwardKinematics(self.model, self.data, q_in)
        right, left = (self.data.oMf[self.robot.frame_id(f)].copy() for f in self.robot.sole_frames)
        com_xy = pin.centerOfMass(self.model, self.data, q_in)[:2].copy()
        chest0 = j[self.index[:_N_CHEST]]
        gaze = self.solve(j, P)
        x, ok = gaze.joints, False
        for _ in range(self.params.balance_iterations):
            q = self.robot.config(x, self._base(x))
            z = pin.centerOfMass(self.model, self.data, q)[2]
            res = self._legs.solve(q, LegTargets(np.array([com_xy[0], com_xy[1], z]), base.rotation,
                                                 left.translation, left.rotation), right)
            if not res.converged:
                break
            legs = res.q[N_BASE_Q:]
            moved = float(np.max(np.abs(legs - x)))
            ok, x = True, legs.copy()
            if moved < self.params.balance_tol_rad:
                break
            x = self.solve(x, P).joints     # aim again from the balanced waist
        if not ok:
            return gaze
        return self._gaze(x, self._base(x), P, float(np.linalg.norm(x[self.index[:_N_CHEST]] - chest0)), True)

    @staticmethod
    def _angles(c: np.ndarray, a: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Off-axis angles and ranges (N,) of points (N, 3) from a camera at ``c`` looking along ``a``."""
        V = P - c
        rng = np.linalg.norm(V, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos = np.where(rng > 0.0, (V @ a) / rng, 1.0)
        return np.arccos(np.clip(cos, -1.0, 1.0)), rng

    def _sees(self, alpha: np.ndarray, rng: np.ndarray) -> np.ndarray:
        cam = self.camera
        return (alpha <= cam.half_fov_rad) & (rng >= cam.min_range_m) & (rng <= cam.max_range_m)

    # ------------------------------------------------------------ sets of points
    def sees(self, joints, points) -> np.ndarray:
        """Whether the camera at ``joints`` (as they are) sees each of ``points`` (N, 3): bool (N,)."""
        j, P = self._joints(joints), self._points(points)
        c, a, _ = self._camera(self.robot.config(j, self._base(j)), False)
        return self._sees(*self._angles(c, a, P))

    def best_gaze(self, joints, points) -> GazeSet:
        """The gaze at the centroid of ``points`` (N, 3) [m, world] and which of them it sees."""
        j, P = self._joints(joints), self._points(points)
        gaze = self.solve(j, P.mean(axis=0))
        alpha, rng = self._angles(gaze.camera_position, gaze.camera_axis, P)
        return GazeSet(gaze, P, alpha, rng, self._sees(alpha, rng))

    def observable(self, joints, points) -> bool | np.ndarray:
        """Whether some gaze reachable from ``joints`` (chest and head within their limits, the
        rest held) sees each point: ``points`` (3,) -> bool, (N, 3) -> bool (N,). The centroid's
        gaze answers for the points it sees; each other point is searched as :meth:`solve` does
        (the head at the current chest, then over the chest grid; without a neck, the chest from
        each) until a gaze sees it, without the least-chest refinement (any gaze that sees it
        will do)."""
        single = np.ndim(points) == 1
        j, P = self._joints(joints), self._points(points)
        seen = self.best_gaze(j, P).in_view.copy()
        if not seen.all():
            base = self._base(j)
            q = self.robot.config(j, base)
            for k in np.flatnonzero(~seen):
                seen[k] = self._can_see(q, base, P[k], np.clip(j[self.index], self.lower, self.upper))
        return bool(seen[0]) if single else seen

    def _can_see(self, q: np.ndarray, base: pin.SE3, point: np.ndarray, x0: np.ndarray) -> bool:
        def sees(x: np.ndarray, alpha: float) -> bool:
            q[N_BASE_Q + self.index] = x
            c, _, _ = self._camera(q, False)
            return bool(self._sees(np.array([alpha]), np.array([np.linalg.norm(point - c)]))[0])

        solves, found = self._search(q, point, x0, sees)
        if found:
            return True
        x, alpha = min(solves, key=lambda s: s[1])
        return sees(*self._aim(q, point, x, self._all))


def surroundings_points(P0: np.ndarray, P1: np.ndarray, radii: np.ndarray, distances_m=(0.06, 0.12),
                        floor_z_m: float = 0.05) -> np.ndarray:
    """Points (N, 3) around a body of capsules (P0, P1 (S, 3), radii (S,)): at the ends and the
    middle of each capsule, in 14 directions (the axes and the cube's diagonals), ``d`` beyond its
    surface for each of ``distances_m``; those inside a capsule grown by the smallest distance
    (another link) or below ``floor_z_m`` left out. The space a balanced reach moves the limbs and
    the trunk through first (issue 31)."""
    dirs = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                     if (x, y, z) != (0, 0, 0) and (abs(x) + abs(y) + abs(z) in (1, 3))], float)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = []
    for a, b, r in zip(P0, P1, radii):
        for t in (0.0, 0.5, 1.0):
            c = a + t * (b - a)
            for d in distances_m:
                pts.append(c + dirs * (r + d))
    P = np.vstack(pts)
    from humanoid_reach_ros.robot.shapes import point_segment_distance
    d = point_segment_distance(P[:, None, :], np.asarray(P0)[None], np.asarray(P1)[None])[0] - np.asarray(radii)[None]
    keep = (d.min(axis=1) >= min(distances_m) - 1e-9) & (P[:, 2] >= floor_z_m)
    return P[keep]


def cover_gazes(solver: "GazeSolver", joints, points: np.ndarray, seen: np.ndarray | None = None,
                max_gazes: int = 4, min_gain: float = 0.03, grid_m: float = 0.15) -> tuple[np.ndarray, dict]:
    """Gaze points (K, 3) whose gazes, from ``joints``, see most of ``points`` (N, 3) not yet
    ``seen`` (N,) bool: a greedy set cover (each gaze the one that sees the most points still
    unseen; candidates: the points on a ``grid_m`` grid, aimed at with :meth:`GazeSolver.solve`),
    at most ``max_gazes``, each adding at least ``min_gain`` of the points. Returns the points
    and figures: how many were seen before and after, how many no candidate sees."""
    P = np.asarray(points, float).reshape(-1, 3)
    done = np.zeros(len(P), bool) if seen is None else np.asarray(seen, bool).copy()
    before = int(done.sum())
    keys = np.round(P / grid_m).astype(int)
    _, first = np.unique(keys, axis=0, return_index=True)
    cover = []
    for k in sorted(first):
        g = solver.solve(joints, P[k])
        if g.visible:
            cover.append((P[k], solver.sees(g.joints, P)))
    chosen = []
    reachable = np.any([c[1] for c in cover], axis=0) if cover else np.zeros(len(P), bool)
    while len(chosen) < max_gazes and cover:
        gains = [int(np.count_nonzero(c[1] & ~done)) for c in cover]
        k = int(np.argmax(gains))
        if gains[k] < max(1, min_gain * len(P)):
            break
        chosen.append(cover[k][0])
        done |= cover[k][1]
    return (np.array(chosen).reshape(-1, 3), {"points": len(P), "seen_before": before, "seen_after": int(done.sum()),
                                              "never_seen": int(np.count_nonzero(~(reachable | done)))})


__all__ = ["DEFAULT_IMAGE", "DEFAULT_MIN_RANGE_M", "Gaze", "GazeCamera", "GazeParams", "GazeSet", "GazeSolver",
           "cover_gazes", "surroundings_points"]
