"""Balance checks of a commanded motion: CoM projection and ZMP in the support polygon.

ZMP from floating-base inverse dynamics (not assumed equal to the CoM projection): for
the commanded configurations ``q_k`` at period ``dt``, velocities and accelerations by
finite differences on the configuration manifold (``v_k = (q_k (-) q_{k-1}) / dt``,
``a_k = (v_{k+1} - v_k) / dt``), RNEA gives the generalised forces; the first six (the
unactuated free flyer, expressed in the base frame) are the wrench the ground must apply.
Moved to the world frame, ``(f, n)`` about the world origin, the ZMP on the floor (z = 0) is

    p_x = -n_y / f_z,    p_y = n_x / f_z.

Support polygon: the convex hull of both soles (the robot description's
``sole_rectangle_m`` about each sole frame); a point is inside with margin ``m`` if its
signed distance to every hull edge is at least ``m``.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from humanoid_reach_ros.robot.model import N_BASE_V, RobotModel


def support_polygon(robot: RobotModel, soles: tuple[pin.SE3, pin.SE3] | None = None) -> np.ndarray:
    """Counter-clockwise convex hull (k, 2) of both sole rectangles."""
    soles = robot.stance_soles if soles is None else soles
    x0, x1, y0, y1 = robot.spec.sole_rectangle
    corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
    pts = np.vstack([(s.rotation @ corners.T).T + s.translation for s in soles])[:, :2]
    return _hull(pts)


def _hull(pts: np.ndarray) -> np.ndarray:
    P = sorted(map(tuple, np.round(pts, 12)))

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in P:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(P):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def polygon_margin(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Signed distance (k,) of each point to the polygon boundary, > 0 inside [m]."""
    pts = np.atleast_2d(pts)
    a, b = poly, np.roll(poly, -1, axis=0)
    e = b - a
    n = np.stack([-e[:, 1], e[:, 0]], 1) / np.linalg.norm(e, axis=1)[:, None]   # inward (CCW)
    return np.min(((pts[:, None, :] - a[None]) * n[None]).sum(-1), axis=1)


def zmp_trajectory(robot: RobotModel, qs: np.ndarray, dt: float) -> np.ndarray:
    """ZMP (k, 2) of the commanded configurations ``qs (k, nq)`` by RNEA (module docstring).
    The first and last configurations are taken at rest (v = 0 before and after)."""
    qs = np.asarray(qs, float)
    if qs.ndim != 2 or qs.shape[1] != robot.model.nq or len(qs) < 1:
        raise ValueError(f"qs must have shape (k, {robot.model.nq})")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be > 0, got {dt}")
    m, d = robot.model, robot.model.createData()
    k = len(qs)
    v = np.zeros((k + 1, m.nv))              # v[i] = velocity between q[i-1] and q[i]
    for i in range(1, k):
        v[i] = pin.difference(m, qs[i - 1], qs[i]) / dt
    out = np.empty((k, 2))
    for i in range(k):
        a = (v[i + 1] - v[i]) / dt
        tau = pin.rnea(m, d, qs[i], v[i], a)
        f_local = pin.Force(tau[:N_BASE_V])
        f_world = pin.XYZQUATToSE3(qs[i][:7]).act(f_local)   # about the world origin, world axes
        fz = f_world.linear[2]
        n = f_world.angular
        out[i] = (-n[1] / fz, n[0] / fz)
    return out


def com_projection(robot: RobotModel, qs: np.ndarray) -> np.ndarray:
    d = robot.model.createData()
    return np.array([pin.centerOfMass(robot.model, d, q)[:2] for q in np.asarray(qs, float)])
