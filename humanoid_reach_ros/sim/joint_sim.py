"""Simulated HRP-2 joint servos and kinematic odometry (no ROS).

``JointSimulator`` is the algorithm behind the ``joint_driver`` node: it holds the
30 joint angles ``q`` and velocities ``dq`` (``RobotModel.joint_names`` order) and a
position target ``q*`` per joint, validates incoming commands, and integrates

    dq_i = clip( (q*_i - q_i) / tau ,  -s * vmax_i, s * vmax_i )

exactly over one step ``dt`` (first-order tracking with time constant ``tau`` =
``time_constant_s``, saturated by the joint's velocity limit ``vmax_i`` times
``velocity_scale`` ``s``). The step is the exponential one,

    Delta q = k (1 - exp(-dt / tau)) (q* - q),   k = min(1, min_i s vmax_i dt / |(1 - exp(-dt / tau)) (q*_i - q_i)|)

(the velocity limit is *coordinated*: where a joint would exceed it, the whole step is scaled
so that every joint keeps moving on the straight line toward the command, as an interpolating
joint controller does; a per-joint clip bent that line and, after a late command, moved one
sole against the other), so a joint never overshoots its target, never moves faster than
``s * vmax_i`` and,
because targets are clipped into ``[lower, upper]`` on arrival, never leaves its
position limits. ``tau = 0`` gives pure rate-limited tracking.

A burst (``BURST_COMMANDS`` or more commands received since the last step: a late delivery
or a stalled driver loop) is played along its own path: the joints pass through each
buffered command in turn at the coordinated velocity limit, then track the last one as
above. Every command of a balanced motion keeps the soles where they are; the straight
line from the joints to the newest command of a 60 ms backlog does not (0.13 mm between
the soles in one bench/session run).

Kinematic odometry (``odometry``): the robot is assumed to stand with both feet
flat and fixed on the floor at their half-sitting stance poses. The waist pose is
computed from the right sole (``RobotModel.base_on_feet``), i.e. the right foot is
assumed not to slip. Nothing enforces that the left foot stays put: its distance
from the stance pose (``OdometryResult.left_foot_slip_m``) is reported so that a
caller can flag leg motions that would drag the left foot.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import RobotModel


@dataclass(frozen=True)
class CommandResult:
    """Outcome of ``JointSimulator.set_command``.

    ``reason`` says why a command was rejected (empty when accepted);
    ``clipped`` names the joints whose targets were clipped into the position limits.
    """

    accepted: bool
    reason: str = ""
    clipped: tuple[str, ...] = ()


@dataclass(frozen=True)
class OdometryResult:
    """Waist pose by feet-fixed kinematic odometry and the left foot's slip."""

    base: pin.SE3                # waist (base_link) pose in the world/stance frame
    left_foot_slip_m: float      # distance of the left sole from its stance pose [m]


#: this many commands received between two steps are a burst, played through one by one (two
#: are the jitter of two clocks of the same period: the newest is tracked as usual)
BURST_COMMANDS = 3
#: at most this many buffered commands (a 1 s backlog at 200 Hz); older ones are dropped
MAX_BUFFERED_COMMANDS = 200


def _bound_ratio(delta: np.ndarray, bound: np.ndarray) -> float:
    """The largest ``|delta_i| / bound_i``: above 1, ``delta / ratio`` is ``delta`` slowed
    together onto the bound (the coordinated velocity limit)."""
    return float(np.max(np.abs(delta) / bound))


def _describe(names: Sequence[str], limit: int = 5) -> str:
    shown = ", ".join(repr(n) for n in list(names)[:limit])
    more = len(names) - limit
    return shown + (f" (+{more} more)" if more > 0 else "")


class JointSimulator:
    """Position-controlled joints with velocity and position limits (see module docstring).

    Parameters
    ----------
    model: the robot (joint names, limits, kinematics for the odometry).
    initial_joints: 30 joint angles to start from [rad]; clipped into the limits.
        Defaults to the half-sitting posture.
    velocity_scale: fraction ``s`` of each joint's velocity limit used as the bound (0, 1].
    time_constant_s: tracking time constant ``tau`` [s], >= 0.
    """

    def __init__(
        self,
        model: RobotModel,
        initial_joints: Sequence[float] | None = None,
        velocity_scale: float = 1.0,
        time_constant_s: float = 0.01,
    ) -> None:
        self.model = model
        self.joint_names: tuple[str, ...] = model.joint_names
        self.n = model.n_joints
        self.lower = np.asarray(model.lower, dtype=float)
        self.upper = np.asarray(model.upper, dtype=float)
        self.velocity_limit = np.asarray(model.velocity_limit, dtype=float)
        self._index = dict(model.joint_index)
        q0 = model.half_sitting_joints if initial_joints is None else initial_joints
        q0 = np.asarray(q0, dtype=float)
        if q0.shape != (self.n,) or not np.all(np.isfinite(q0)):
            raise ValueError(f"initial_joints must be {self.n} finite angles, got shape {q0.shape}")
        self.q = np.clip(q0, self.lower, self.upper)
        self.dq = np.zeros(self.n)
        self.target = self.q.copy()
        self._received: deque[np.ndarray] = deque(maxlen=MAX_BUFFERED_COMMANDS)  # since the last step
        self._bursting = False       # playing a burst through, over several steps
        self.velocity_scale = velocity_scale
        self.time_constant_s = time_constant_s
        # counters for diagnostics
        self.accepted_count = 0
        self.rejected_count = 0
        self.last_rejection: str = ""
        self.clip_events = 0                       # accepted commands with >= 1 clipped target
        self.clip_count = np.zeros(self.n, dtype=np.int64)  # clipped targets per joint
        self.last_command_time: float | None = None
        self.commanded_velocity = np.zeros(self.n)  # last validated velocities (informational)
        self._odom_key: bytes | None = None
        self._odom: OdometryResult | None = None

    # ------------------------------------------------------------ parameters
    @property
    def velocity_scale(self) -> float:
        return self._velocity_scale

    @velocity_scale.setter
    def velocity_scale(self, value: float) -> None:
        if not (0.0 < value <= 1.0):
            raise ValueError(f"velocity_scale must be in (0, 1], got {value}")
        self._velocity_scale = float(value)

    @property
    def time_constant_s(self) -> float:
        return self._tau

    @time_constant_s.setter
    def time_constant_s(self, value: float) -> None:
        if not (value >= 0.0 and math.isfinite(value)):
            raise ValueError(f"time_constant_s must be finite and >= 0, got {value}")
        self._tau = float(value)

    @property
    def velocity_bound(self) -> np.ndarray:
        """Per-joint speed bound ``s * vmax`` [rad/s]."""
        return self._velocity_scale * self.velocity_limit

    # ------------------------------------------------------------ commands
    def validate_command(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] | None = None,
    ) -> str:
        """Reason why the command is unusable, or ``""`` when it is well formed.

        A command names each joint once, gives one finite position per name and,
        optionally, one finite velocity per name (an empty velocity array means none).
        """
        names = list(names)
        n_pos = len(positions)
        n_vel = 0 if velocities is None else len(velocities)
        if not names:
            return "empty command: no joint names"
        if n_pos != len(names):
            return f"length mismatch: {len(names)} joint names but {n_pos} positions"
        if n_vel not in (0, len(names)):
            return f"length mismatch: {len(names)} joint names but {n_vel} velocities (need 0 or {len(names)})"
        unknown = [n for n in names if n not in self._index]
        if unknown:
            return f"unknown joint names: {_describe(unknown)}"
        if len(set(names)) != len(names):
            dup = sorted(n for n, c in Counter(names).items() if c > 1)
            return f"duplicate joint names: {_describe(dup)}"
        pos = np.asarray(positions, dtype=float)
        bad = ~np.isfinite(pos)
        if bad.any():
            return "non-finite positions: " + _describe([f"{names[i]}={pos[i]}" for i in np.flatnonzero(bad)])
        if n_vel:
            vel = np.asarray(velocities, dtype=float)
            bad = ~np.isfinite(vel)
            if bad.any():
                return "non-finite velocities: " + _describe([f"{names[i]}={vel[i]}" for i in np.flatnonzero(bad)])
        return ""

    def set_command(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        velocities: Sequence[float] | None = None,
        now: float | None = None,
    ) -> CommandResult:
        """Set position targets for the named joints (a subset is fine).

        A rejected command changes nothing: the last good targets are held. Targets
        outside ``[lower, upper]`` are clipped and counted (``clip_count``,
        ``clip_events``). ``now`` [s] is the receipt time used by ``command_age``
        (``None``: the command carries no time and never goes stale).
        Velocities, when given, are validated and kept in ``commanded_velocity``;
        tracking is on position only.
        """
        reason = self.validate_command(names, positions, velocities)
        if reason:
            self.rejected_count += 1
            self.last_rejection = reason
            return CommandResult(False, reason)
        idx = np.fromiter((self._index[n] for n in names), dtype=np.intp, count=len(names))
        pos = np.asarray(positions, dtype=float)
        clipped_pos = np.clip(pos, self.lower[idx], self.upper[idx])
        clipped_mask = clipped_pos != pos
        self.target[idx] = clipped_pos
        self._received.append(self.target.copy())
        if velocities is not None and len(velocities):
            self.commanded_velocity[idx] = np.asarray(velocities, dtype=float)
        clipped: tuple[str, ...] = ()
        if clipped_mask.any():
            self.clip_events += 1
            self.clip_count[idx[clipped_mask]] += 1
            clipped = tuple(names[i] for i in np.flatnonzero(clipped_mask))
        self.accepted_count += 1
        self.last_command_time = now
        return CommandResult(True, "", clipped)

    def hold(self) -> None:
        """Make the current positions the targets (used when commands go stale)."""
        self.target[:] = self.q
        self._received.clear()
        self._bursting = False
        self.commanded_velocity[:] = 0.0

    def command_age(self, now: float) -> float:
        """Seconds since the last accepted command (``inf`` if none was ever accepted)."""
        if self.last_command_time is None:
            return math.inf
        return now - self.last_command_time

    # ------------------------------------------------------------ motion
    def step(self, dt: float) -> np.ndarray:
        """Advance ``dt`` seconds; returns ``q`` (also updates ``dq``, the step's mean velocity)."""
        if dt <= 0.0:
            self.dq[:] = 0.0
            return self.q
        bound = self.velocity_bound * dt
        q = self.q.copy()
        budget = 1.0            # fraction of this step's motion at the velocity bound still free
        if self._bursting or len(self._received) >= BURST_COMMANDS:
            # a burst: through each buffered command in turn (all but the newest) at the coordinated
            # limit, over as many steps as it takes (commands arriving meanwhile join the queue)
            while len(self._received) > 1:
                diff = self._received[0] - q
                need = _bound_ratio(diff, bound)
                if need <= budget:
                    q = self._received.popleft()
                    budget -= need
                    continue
                q = q + diff * (budget / need)
                budget = 0.0
                break
            self._bursting = len(self._received) > 1
        if not self._bursting:
            self._received.clear()      # the newest is self.target
        if budget > 0.0:
            gain = 1.0 if self._tau == 0.0 else -math.expm1(-dt / self._tau)
            delta = gain * (self.target - q)
            # coordinated velocity limit: where a joint would exceed its bound the whole step is scaled
            # down, so every joint keeps moving on the straight line toward the command (a per-joint
            # clip bends it: after a late /joint_command the legs caught up joint by joint and the left
            # sole moved 0.8 mm from the right for 15 ms, measured in bench/session)
            need = _bound_ratio(delta, bound * budget)
            q = q + (delta / need if need > 1.0 else delta)
        q_new = np.clip(q, self.lower, self.upper)
        self.dq[:] = (q_new - self.q) / dt
        self.q[:] = q_new
        return self.q

    # ------------------------------------------------------------ odometry
    def odometry(self) -> OdometryResult:
        """Waist pose with the right sole fixed at its stance pose, and the left foot's slip.

        Kinematic odometry: assumes the right foot does not slip (and the floor is the
        stance plane). The result is cached while the joint angles do not change.
        """
        key = self.q.tobytes()
        if self._odom is None or key != self._odom_key:
            joints = self.q.copy()
            base = self.model.base_on_feet(joints)
            left = self.model.frame_pose(self.model.config(joints, base), self.model.sole_frames[1])
            slip = float(np.linalg.norm(left.translation - self.model.stance_soles[1].translation))
            self._odom_key = key
            self._odom = OdometryResult(base, slip)
        return OdometryResult(self._odom.base.copy(), self._odom.left_foot_slip_m)

    # ------------------------------------------------------------ helpers
    def positions_dict(self) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.joint_names, self.q)}
