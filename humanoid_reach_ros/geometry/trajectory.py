"""Path -> executable trajectory (Kanehiro et al. Sec. IV), monotone cubic interpolation.

"Durations to move between neighboring postures in the path are computed as the
maximum difference of joint angles divided by a given joint velocity. An initial
trajectory is then obtained by interpolating postures using clamped cubic spline."

For waypoints ``q_0 .. q_{k-1}`` (``(k, n)``) and joint velocities ``v_j``::

    T_i = max( T_min , max_j |q_{i+1,j} - q_{i,j}| / v_j ) ,   t_0 = 0 , t_{i+1} = t_i + T_i

Deviation from the paper: Kanehiro Sec. IV interpolates with a clamped cubic spline;
that overshoots between waypoints (measured: RARM_JOINT2 1.6181 > 1.6057, a planned
trajectory the executor refused because its samples left the joint limits the planner
had checked at every waypoint), PCHIP cannot. ``q(t)`` is the piecewise cubic Hermite
interpolant through ``(t_i, q_i)`` with the Fritsch-Carlson (PCHIP, Brodlie's weighted
harmonic mean) slopes, zero at both ends (at rest at both ends, as the clamped spline
was). With ``h_i = t_{i+1} - t_i`` and ``d_i = (q_{i+1} - q_i) / h_i`` (per joint)::

    m_0 = m_{k-1} = 0
    m_i = 0                                            if d_{i-1} d_i <= 0   (local extremum or flat)
    m_i = (w_1 + w_2) / (w_1 / d_{i-1} + w_2 / d_i)    otherwise,  w_1 = 2 h_i + h_{i-1},  w_2 = h_i + 2 h_{i-1}

Why it cannot overshoot: on segment ``i`` (``u = s / h_i`` in ``[0, 1]``, ``s = t - t_i``)
the Hermite cubic's velocity is::

    q'(u) = d_i [6 u (1 - u) + alpha (1 - u)(1 - 3u) + beta u (3u - 2)],
    alpha = m_i / d_i ,  beta = m_{i+1} / d_i .

If ``d_i = 0`` both end slopes are 0 (the rule above: a flat secant or a local extremum
on either side gives ``m = 0``), so the segment is constant. Otherwise ``m_i``, ``m_{i+1}``
are 0 or of the sign of ``d_i`` (zero slopes at local extrema), so ``alpha, beta >= 0``;
and ``alpha <= (w_1 + w_2) / w_2 = 3 (h_{i-1} + h_i) / (h_i + 2 h_{i-1}) <= 3`` (the
harmonic mean without its other, same-signed term), likewise ``beta <= (w_1 + w_2) / w_1
<= 3`` -- the Fritsch-Carlson sufficient condition ``(alpha, beta) in [0, 3]^2``. The
bracket is linear in ``(alpha, beta)``, so its minimum over that square is at a corner:
``6u(1-u)``, ``3(1-u)^2``, ``3u^2``, ``3(2u-1)^2``, all ``>= 0``. Hence ``q'`` has the
sign of ``d_i`` on the whole segment, which is monotone, and each joint stays within
``[min(q_i, q_{i+1}), max(q_i, q_{i+1})]``: a path whose waypoints are within the joint
limits gives a trajectory within them (up to the rounding of the cubic's evaluation,
~1e-16 rad). :meth:`SplineTrajectory.check_limits` verifies it exactly anyway.

The price: ``q''`` jumps at the knots (C1, where the clamped spline was C2); nothing here
uses the acceleration but the JointTrajectory samples (right-hand value at a knot).

The durations make the *piecewise-linear* interpolation respect ``|q_j'| <= v_j``; the
cubic does not: it starts and stops at rest and is smooth, so between waypoints it
moves faster (for a single segment the peak is ``1.5 v_j``; PCHIP slopes reach up to
``3 d``). :attr:`SplineTrajectory.max_velocity` reports the exact peak and
``TrajectoryOptions.respect_velocity_limit`` rescales time by
``kappa = max_j max|q_j'| / v_j`` (``v`` there: ``velocity_limit`` when given): the slopes are
time-scale equivariant (``d`` and
``m`` scale by ``1 / kappa``, the weights' ratios do not change), so the interpolant
through the same points at times ``kappa t_i`` is ``q(t / kappa)`` with velocities
``q' / kappa``, which restores the bound exactly.

It sits in ``geometry/`` (below both) because planning makes these trajectories and
control follows them as its reference; control never imports planning.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicHermiteSpline


@dataclass(frozen=True)
class TrajectoryOptions:
    """``joint_velocity``: ``v`` [rad/s or m/s] of the durations rule, scalar or one per joint;
    ``min_segment_duration_s``: ``T_min`` (> 0, also used for repeated waypoints);
    ``respect_velocity_limit``: stretch time until the exact peak ``max_velocity <=
    velocity_limit`` (per joint; None: ``joint_velocity``)."""

    joint_velocity: float | tuple[float, ...] = 0.5
    min_segment_duration_s: float = 0.01
    respect_velocity_limit: bool = False
    velocity_limit: float | tuple[float, ...] | None = None


def segment_durations(waypoints: np.ndarray, joint_velocity: float | np.ndarray,
                      min_duration_s: float) -> np.ndarray:
    """``T_i = max(T_min, max_j |q_{i+1,j} - q_{i,j}| / v_j)``, shape ``(k - 1,)``."""
    Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
    v = np.broadcast_to(np.asarray(joint_velocity, dtype=float), (Q.shape[1],))
    if np.any(v <= 0) or not min_duration_s > 0:
        raise ValueError("joint velocities and the minimum duration must be > 0")
    return np.maximum(min_duration_s, np.max(np.abs(np.diff(Q, axis=0)) / v, axis=1))


def pchip_slopes(times: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Knot slopes ``m`` (``(k, n)``) of the monotone interpolant (module docstring):
    Brodlie's weighted harmonic mean of the neighbouring secants where they have the same
    sign, 0 at local extrema, flat secants and both ends.

    The harmonic mean is computed as ``(w_1 + w_2) d_{i-1} d_i / (w_1 d_i + w_2 d_{i-1})``
    (no division by a tiny secant); both terms of the denominator have the sign of
    ``d``, so it is never 0 where the secants agree in sign."""
    Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
    t = np.asarray(times, dtype=float).reshape(-1)
    m = np.zeros_like(Q)
    if len(Q) < 3:
        return m
    h = np.diff(t)[:, None]
    d = np.diff(Q, axis=0) / h
    h0, h1, d0, d1 = h[:-1], h[1:], d[:-1], d[1:]
    w1, w2 = 2.0 * h1 + h0, h1 + 2.0 * h0
    same = d0 * d1 > 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        hm = (w1 + w2) * d0 * d1 / (w1 * d1 + w2 * d0)
    m[1:-1] = np.where(same & np.isfinite(hm), hm, 0.0)
    return m


@dataclass(frozen=True, eq=False)
class TrajectoryPoints:
    """Samples ready for a ``JointTrajectory``: ``times (m,)``, the rest ``(m, n)``."""

    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray


class LimitViolation(NamedTuple):
    """Where a trajectory leaves ``[lower, upper]``: ``joint`` index, ``time`` [s, the
    trajectory's clock] and ``value`` of the joint's extreme on the first offending segment
    ``segment`` (between waypoints ``segment`` and ``segment + 1``)."""

    joint: int
    time: float
    value: float
    segment: int


class SplineTrajectory:
    """Monotone piecewise cubic (PCHIP, zero end slopes) through waypoints at times ``t_i``
    (module docstring). The class keeps its historical name: the executor rebuilds the
    same interpolant from the transmitted samples (``io/exec_msgs.py``)."""

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
            self._spline = CubicHermiteSpline(t, Q, pchip_slopes(t, Q), axis=0)

    @classmethod
    def from_path(cls, waypoints: np.ndarray,
                  options: TrajectoryOptions = TrajectoryOptions()) -> "SplineTrajectory":
        """Times from :func:`segment_durations`, optionally rescaled (see module doc)."""
        Q = np.atleast_2d(np.asarray(waypoints, dtype=float))
        T = segment_durations(Q, options.joint_velocity, options.min_segment_duration_s) if len(Q) > 1 else np.zeros(0)
        traj = cls(Q, np.concatenate([[0.0], np.cumsum(T)]))
        if options.respect_velocity_limit and len(Q) > 1:
            bound = options.joint_velocity if options.velocity_limit is None else options.velocity_limit
            v = np.broadcast_to(np.asarray(bound, dtype=float), (Q.shape[1],))
            if np.any(~(v > 0)):
                raise ValueError("velocity limits must be > 0")
            kappa = float(np.max(traj.max_velocity / v))
            if kappa > 1.0:
                traj = cls(Q, traj.times * kappa)
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
        """``q''(t)``; at a knot the value of the segment that starts there (C1 interpolant)."""
        return self._eval(t, 2)

    def evaluate(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, q', q'')`` at ``t`` (scalar: ``(n,)`` each; array ``(m,)``: ``(m, n)``)."""
        return self.position(t), self.velocity(t), self.acceleration(t)

    @property
    def max_velocity(self) -> np.ndarray:
        """Exact ``max_t |q_j'(t)|`` per joint, shape ``(n,)``.

        On each segment ``q' = 3 c_0 s^2 + 2 c_1 s + c_2`` (``s = t - t_i``, ``c`` the PPoly
        coefficients); the maximum of ``|q'|`` is at ``s = 0``, ``s = T_i`` or the vertex
        ``s* = -c_1 / (3 c_0)``.
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

    def segment_extrema(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Exact ``(low, s_low, high, s_high)`` of every joint on every segment, each
        ``(k - 1, n)`` (``s`` from the segment's start).

        The extrema of ``p(s) = c_0 s^3 + c_1 s^2 + c_2 s + c_3`` on ``[0, h_i]`` are at the
        ends (the waypoints themselves, taken exactly) or at the roots in ``(0, h_i)`` of
        ``p'(s) = a s^2 + b s + c`` (``a = 3 c_0, b = 2 c_1, c = c_2``), computed in the
        cancellation-free form ``r = q / a, c / q`` with
        ``q = -(b + sign(b) sqrt(b^2 - 4 a c)) / 2`` (``a = 0``: the linear root ``c / q
        = -c / b``; no real root when the discriminant is negative). For PCHIP no interior
        extremum lies beyond the segment's end values (proof in the module docstring); this
        computes the extrema rather than assuming that, so it holds for any cubic PPoly.
        """
        Q = self.waypoints
        if self._spline is None:
            z = np.zeros((0, self.n_joints))
            return z, z, z.copy(), z.copy()
        c = self._spline.c
        c0, c1, c2, c3 = c[0], c[1], c[2], c[3]
        h = np.broadcast_to(np.diff(self.times)[:, None], c0.shape)
        a, b = 3.0 * c0, 2.0 * c1
        disc = b * b - 4.0 * a * c2
        sq = np.sqrt(np.maximum(disc, 0.0))
        q = -0.5 * (b + np.where(b >= 0.0, sq, -sq))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            roots = np.stack([q / a, c2 / q])                      # (2, k-1, n), inf/nan where absent
        # roots within 1e-9 h of an end are that end (whose value is the waypoint, exact):
        # a zero knot slope (c_2 = 0) puts a root at s = 0, computed as a tiny positive s
        # whose rounded cubic was 2e-16 rad past the waypoint (a false violation at a
        # waypoint on its limit, seen on random paths)
        ok = (disc >= 0.0) & np.isfinite(roots) & (roots > 1e-9 * h) & (roots < (1.0 - 1e-9) * h)
        s = np.where(ok, roots, 0.0)
        val = np.where(ok, ((c0 * s + c1) * s + c2) * s + c3, Q[:-1])
        # candidates: s = 0 (q_i), s = h (q_{i+1}), the two roots
        vals = np.concatenate([Q[None, :-1], Q[None, 1:], val])    # (4, k-1, n)
        ss = np.concatenate([np.zeros((1,) + h.shape), h[None], s])
        lo_i, hi_i = np.argmin(vals, axis=0)[None], np.argmax(vals, axis=0)[None]
        take = lambda a_, i: np.take_along_axis(a_, i, axis=0)[0]  # noqa: E731
        return take(vals, lo_i), take(ss, lo_i), take(vals, hi_i), take(ss, hi_i)

    def position_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Exact ``(min_t q_j(t), max_t q_j(t))`` per joint, each ``(n,)`` (:meth:`segment_extrema`)."""
        if self._spline is None:
            return self.waypoints[0].copy(), self.waypoints[0].copy()
        lo, _, hi, _ = self.segment_extrema()
        return lo.min(axis=0), hi.max(axis=0)

    def max_position_excursion(self) -> np.ndarray:
        """Exact overshoot beyond the waypoints per joint, ``(n,)``: how far ``q_j(t)`` goes
        below ``min_i q_{i,j}`` or above ``max_i q_{i,j}`` (0 for PCHIP up to rounding)."""
        lo, hi = self.position_range()
        return np.maximum(np.maximum(self.waypoints.min(axis=0) - lo, hi - self.waypoints.max(axis=0)), 0.0)

    def check_limits(self, lower: np.ndarray, upper: np.ndarray, tol: float = 1e-12) -> LimitViolation | None:
        """First place where a joint leaves ``[lower - tol, upper + tol]``, exactly (extrema
        of each segment, :meth:`segment_extrema`; not by sampling), or None. The default
        ``tol`` only absorbs the rounding of a cubic's evaluation (~1e-16 rad).

        "First": the earliest offending segment; in it the joint with the largest excess
        and the time and value of that joint's extreme. The waypoints are candidates too,
        so a waypoint outside the limits is reported (at its time)."""
        lower = np.broadcast_to(np.asarray(lower, dtype=float), (self.n_joints,))
        upper = np.broadcast_to(np.asarray(upper, dtype=float), (self.n_joints,))
        if self._spline is None:
            q = self.waypoints[0]
            ex = np.maximum(lower - q, q - upper)
            if np.any(ex > tol):
                j = int(np.argmax(ex))
                return LimitViolation(j, float(self.times[0]), float(q[j]), 0)
            return None
        lo, s_lo, hi, s_hi = self.segment_extrema()
        below, above = lower - lo, hi - upper                       # excess, (k-1, n)
        excess = np.maximum(below, above)
        bad = excess > tol
        if not np.any(bad):
            return None
        i = int(np.argmax(np.any(bad, axis=1)))
        j = int(np.argmax(np.where(bad[i], excess[i], -np.inf)))
        s, value = (s_hi[i, j], hi[i, j]) if above[i, j] >= below[i, j] else (s_lo[i, j], lo[i, j])
        return LimitViolation(j, float(self.times[i] + s), float(value), i)

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
    """Kanehiro Sec. IV: durations by the max-joint-difference rule; monotone cubic (PCHIP,
    zero end slopes) where the paper has a clamped cubic spline (module docstring)."""
    return SplineTrajectory.from_path(waypoints, options)
