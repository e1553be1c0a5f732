"""Path -> executable trajectory (Kanehiro et al. Sec. IV).

"Durations to move between neighboring postures in the path are computed as the
maximum difference of joint angles divided by a given joint velocity. An initial
trajectory is then obtained by interpolating postures using clamped cubic spline."

For waypoints ``q_0 .. q_{k-1}`` (``(k, n)``) and joint velocities ``v_j``::

    T_i = max( T_min , max_j |q_{i+1,j} - q_{i,j}| / v_j ) ,   t_0 = 0 , t_{i+1} = t_i + T_i

and ``q(t)`` is the cubic spline through ``(t_i, q_i)`` with ``q'(t_0) = q'(t_end) = 0``
(clamped). The durations make the *piecewise-linear* interpolation respect
``|q_j'| <= v_j``; the spline does not: it starts and stops at rest and is
smooth, so between waypoints it moves faster (for a single segment the peak is
``1.5 v_j``). :attr:`SplineTrajectory.max_velocity` reports the exact peak and
``TrajectoryOptions.respect_velocity_limit`` rescales time by
``alpha = max_j max|q_j'| / v_j`` (a spline through the same points at times
``alpha t_i`` has velocities ``q'/alpha``), which restores the bound.

It sits in ``geometry/`` (below both) because planning makes these trajectories and
control follows them as its reference; control never imports planning.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline


@dataclass(frozen=True)
class TrajectoryOptions:
    """``joint_velocity``: ``v`` [rad/s or m/s], scalar or one per joint;
    ``min_segment_duration_s``: ``T_min`` (> 0, also used for repeated waypoints)."""

    joint_velocity: float | tuple[float, ...] = 0.5
    min_segment_duration_s: float = 0.01
    respect_velocity_limit: bool = False


def segment_durations(waypoints: np.ndarray, joint_velocity: float | np.ndarray,
                      min_duration_s: float) -> np.ndarray:
    """``T_i = max(T_min, max_j |q_{i+1,j} - q_{i,j}| / v_j)``, shape ``(k - 1,)``."""
    Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
    v = np.broadcast_to(np.asarray(joint_velocity, dtype=float), (Q.shape[1],))
    if np.any(v <= 0) or not min_duration_s > 0:
        raise ValueError("joint velocities and the minimum duration must be > 0")
    return np.maximum(min_duration_s, np.max(np.abs(np.diff(Q, axis=0)) / v, axis=1))


@dataclass(frozen=True, eq=False)
class TrajectoryPoints:
    """Samples ready for a ``JointTrajectory``: ``times (m,)``, the rest ``(m, n)``."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray


class SplineTrajectory:
    """Clamped cubic spline through waypoints at times ``t_i``."""

    def __init__(self, waypoints: np.ndarray, times: np.ndarray) -> None:
        Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
        t = np.asarray(times, dtype=float).reshape(-1)
        if len(Q) != len(t):
            raise ValueError("one time per waypoint")
        self.waypoints = Q
        self.times = t
        if len(Q) == 1:  # at rest: a constant "spline" of zero duration
            self._spline = None
        else:
            if np.any(np.diff(t) <= 0):
                raise ValueError("times must be strictly increasing")
            self._spline = CubicSpline(t, Q, axis=0, bc_type="clamped")

    @classmethod
    def from_path(cls, waypoints: np.ndarray,
                  options: TrajectoryOptions = TrajectoryOptions()) -> "SplineTrajectory":
        """Times from :func:`segment_durations`, optionally rescaled (see module doc)."""
        Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
        T = segment_durations(Q, options.joint_velocity, options.min_segment_duration_s) if len(Q) > 1 else np.zeros(0)
        traj = cls(Q, np.concatenate([[0.0], np.cumsum(T)]))
        if options.respect_velocity_limit and len(Q) > 1:
            v = np.broadcast_to(np.asarray(options.joint_velocity, dtype=float), (Q.shape[1],))
            alpha = float(np.max(traj.max_velocity / v))
            if alpha > 1.0:
                traj = cls(Q, traj.times * alpha)
        return traj

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def n_joints(self) -> int:
        return int(self.waypoints.shape[1])

    def _eval(self, t: float | np.ndarray, nu: int) -> np.ndarray:
        tt = np.clip(np.asarray(t, dtype=float), self.times[0], self.times[-1])
        if self._spline is None:
            shape = tt.shape + (self.n_joints,)
            return np.broadcast_to(self.waypoints[0], shape).copy() if nu == 0 else np.zeros(shape)
        return self._spline(tt, nu)

    def position(self, t: float | np.ndarray) -> np.ndarray:
        """``q(t)``; ``t`` is clamped to ``[t_0, t_end]`` (at rest outside)."""
        return self._eval(t, 0)

    def velocity(self, t: float | np.ndarray) -> np.ndarray:
        return self._eval(t, 1)

    def acceleration(self, t: float | np.ndarray) -> np.ndarray:
        return self._eval(t, 2)

    def evaluate(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, q', q'')`` at ``t`` (scalar: ``(n,)`` each; array ``(m,)``: ``(m, n)``)."""
        return self.position(t), self.velocity(t), self.acceleration(t)

    @property
    def max_velocity(self) -> np.ndarray:
        """Exact ``max_t |q_j'(t)|`` per joint, shape ``(n,)``.

        On each segment ``q' = 3 c_0 s^2 + 2 c_1 s + c_2`` (``s = t - t_i``); the
        maximum of ``|q'|`` is at ``s = 0``, ``s = T_i`` or the vertex ``s* = -c_1 / (3 c_0)``.
        """
        if self._spline is None:
            return np.zeros(self.n_joints)
        c = self._spline.c  # (4, k-1, n)
        h = np.diff(self.times)[:, None]
        c0, c1, c2 = c[0], c[1], c[2]
        v = lambda s: 3 * c0 * s * s + 2 * c1 * s + c2  # noqa: E731
        with np.errstate(divide="ignore", invalid="ignore"):
            s_star = np.where(np.abs(c0) > 1e-15, -c1 / (3 * c0), 0.0)
        s_star = np.clip(np.nan_to_num(s_star), 0.0, h)
        cand = np.stack([np.abs(v(np.zeros_like(h))), np.abs(v(h + 0 * c0)), np.abs(v(s_star))])
        return cand.max(axis=(0, 1))

    def sample_times(self, period_s: float) -> np.ndarray:
        """``0, p, 2p, ...`` up to the end, the end time always included (last step ``<= p``)."""
        if not period_s > 0:
            raise ValueError("period_s must be > 0")
        n = int(np.floor(self.duration / period_s + 1e-9))
        t = self.times[0] + period_s * np.arange(n + 1)
        if self.times[-1] - t[-1] > 1e-9:
            t = np.append(t, self.times[-1])
        else:
            t[-1] = self.times[-1]
        return t

    def to_points(self, period_s: float) -> TrajectoryPoints:
        """Resample at ``period_s`` (e.g. 5 ms for execution, coarser for a JointTrajectory);
        times are relative to ``t_0``."""
        t = self.sample_times(period_s)
        q, qd, qdd = self.evaluate(t)
        return TrajectoryPoints(t - self.times[0], q, qd, qdd)


def path_to_trajectory(waypoints: np.ndarray, options: TrajectoryOptions = TrajectoryOptions()) -> SplineTrajectory:
    """Kanehiro Sec. IV: durations by the max-joint-difference rule, clamped cubic spline."""
    return SplineTrajectory.from_path(waypoints, options)
