"""Balance and contact figures of a MuJoCo state: centre of pressure, support polygon margin,
sole slip, base tilt, hand forces, capture point and the fall flag.

* **Centre of pressure** (per foot and of the whole body): with ``f_i`` the normal force of
  contact ``i`` (``mj_contactForce``, the first component in the contact frame) and ``p_i``
  its point, ``CoP = sum_i f_i p_i / sum_i f_i`` over the contacts between a foot (its body
  and the bodies below it) and the world; the whole-body CoP over both feet's contacts.
* **Support polygon**: the convex hull of the sole rectangles (robot description's
  ``sole_rectangle_m`` about each measured sole frame) of the feet that carry load
  (normal force above :data:`LOADED_N`), in the floor plane. Its **margin** is the signed
  distance from the CoP to the polygon's edge: positive inside, negative outside.
* **Sole slip**: how far each sole frame has moved in the floor plane (x, y) since the
  reference (the start of the stand): tangential drift. The sole's sinking into the floor (the
  soft contact's penetration, about a millimetre) is not slip and is left out.
* **Base tilt**: the angle between the base link's z axis and the world's vertical.
* **Hand forces**: the magnitude of the total contact force between each hand (the body
  carrying the hand frame and those below it) and the world.
* **Capture point** (the linear inverted pendulum's): ``xi = c + cdot / omega``,
  ``omega = sqrt(g / h)`` with ``c`` the centre of mass and ``h`` its height above the soles.
* **Fall** when the base has dropped ``base_drop_m`` below where its joints hold it with the
  right sole flat on its stance pose (``RobotModel.base_on_feet`` of the measured joints: a
  crouch the plan commands is no fall, a robot tipping over its sole edge or sinking is; without
  that height, its start height), tilts more
  than ``tilt_deg``, or the capture point is more than ``capture_point_out_m`` outside the
  support polygon (of both soles when none carries load); thresholds in physics.yaml.

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel

#: a foot carries load above this normal force [N] (its rectangle joins the support polygon)
LOADED_N = 1.0


@dataclass(frozen=True)
class StandReference:
    """What slip and drop are measured against: each sole's (x, y) and the base height at the start."""

    sole_xy: tuple[np.ndarray, np.ndarray]
    base_z: float


@dataclass(frozen=True)
class ContactMetrics:
    """One state's figures (module doc); points in the world frame [m], forces [N]."""

    foot_force_n: tuple[float, float]              # right, left normal force
    foot_cop: tuple[np.ndarray | None, np.ndarray | None]   # (x, y) per foot; None without contact
    cop: np.ndarray | None                         # (x, y) of both feet; None without foot contact
    support_polygon: np.ndarray                    # (k, 2), counter-clockwise
    cop_margin_m: float                            # signed; -inf without foot contact
    sole_slip_m: tuple[float, float]
    base_tilt_deg: float
    base_height_m: float
    com: np.ndarray
    capture_point: np.ndarray                      # (x, y)
    capture_point_out_m: float                     # distance outside the polygon; 0 inside
    hand_force_n: dict[str, float]
    fallen: bool
    fall_reason: str


# ------------------------------------------------------------------ polygons
def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points, counter-clockwise, no collinear points (Andrew's monotone chain)."""
    pts = sorted(set(map(tuple, np.round(np.asarray(points, float), 12))))
    if len(pts) <= 2:
        return np.array(pts, float)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], float)


def polygon_margin(polygon: np.ndarray, p: np.ndarray) -> float:
    """Signed distance from ``p`` to the edge of the convex counter-clockwise ``polygon``:
    positive inside (the distance to the nearest edge), negative outside (minus the distance
    to the polygon)."""
    a = np.asarray(polygon, float)
    b = np.roll(a, -1, axis=0)
    e = b - a
    length = np.linalg.norm(e, axis=1)
    n_out = np.column_stack([e[:, 1], -e[:, 0]]) / length[:, None]      # outward for counter-clockwise
    signed = np.einsum("ij,ij->i", np.asarray(p, float) - a, n_out)    # > 0 outside that edge's line
    if np.all(signed <= 0.0):
        return float(-signed.max())
    t = np.clip(np.einsum("ij,ij->i", np.asarray(p, float) - a, e) / length**2, 0.0, 1.0)
    closest = a + t[:, None] * e
    return -float(np.linalg.norm(closest - p, axis=1).min())


# ------------------------------------------------------------------ the state's figures
def sole_poses(pm: PhysicsModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """World 4x4 poses of the right and left sole frames."""
    out = []
    for body, T in zip(pm.sole_bodies, pm.sole_in_body):
        W = np.eye(4)
        W[:3, :3] = data.xmat[body].reshape(3, 3)
        W[:3, 3] = data.xpos[body]
        out.append(W @ T)
    return out[0], out[1]


def stand_reference(pm: PhysicsModel, data: mujoco.MjData) -> StandReference:
    """The reference of slip and drop: the soles' (x, y) and the base height now."""
    r, l_ = sole_poses(pm, data)
    return StandReference((r[:2, 3].copy(), l_[:2, 3].copy()), float(data.xpos[pm.root_body][2]))


def _rectangle_xy(pm: PhysicsModel, sole: np.ndarray) -> np.ndarray:
    x0, x1, y0, y1 = pm.robot.spec.sole_rectangle
    corners = np.array([[x0, y0, 0.0, 1.0], [x1, y0, 0.0, 1.0], [x1, y1, 0.0, 1.0], [x0, y1, 0.0, 1.0]])
    return (corners @ sole.T)[:, :2]


def contact_metrics(pm: PhysicsModel, data: mujoco.MjData, ref: StandReference,
                    base_z_held: float | None = None) -> ContactMetrics:
    """The figures of the state in ``data`` (after ``mj_step`` or ``mj_forward``), module doc;
    ``base_z_held``: the base height the measured joints hold with the feet on the floor (None:
    the reference's start height)."""
    model = pm.model
    force6 = np.zeros(6)
    fsum = [0.0, 0.0]
    moment = [np.zeros(2), np.zeros(2)]
    hand = {side: np.zeros(3) for side in pm.hand_body_sets}
    world = pm.world_geoms
    for i in range(data.ncon):
        c = data.contact[i]
        ga, gb = int(c.geom1), int(c.geom2)
        if (ga in world) == (gb in world):
            continue
        robot_body = int(model.geom_bodyid[gb if ga in world else ga])
        mujoco.mj_contactForce(model, data, i, force6)
        fn = float(force6[0])
        for k, feet in enumerate(pm.foot_body_sets):
            if robot_body in feet:
                fsum[k] += fn
                moment[k] += fn * c.pos[:2]
        for side, bodies in pm.hand_body_sets.items():
            if robot_body in bodies:
                hand[side] += force6[:3] @ c.frame.reshape(3, 3)
    foot_cop = tuple(moment[k] / fsum[k] if fsum[k] > 0.0 else None for k in range(2))
    total = fsum[0] + fsum[1]
    cop = (moment[0] + moment[1]) / total if total > 0.0 else None
    soles = sole_poses(pm, data)
    loaded = [k for k in range(2) if fsum[k] > LOADED_N] or [0, 1]
    polygon = convex_hull(np.vstack([_rectangle_xy(pm, soles[k]) for k in loaded]))
    margin = polygon_margin(polygon, cop) if cop is not None else -math.inf
    slip = tuple(float(np.linalg.norm(soles[k][:2, 3] - ref.sole_xy[k])) for k in range(2))
    R = data.xmat[pm.root_body].reshape(3, 3)
    tilt = math.degrees(math.acos(float(np.clip(R[2, 2], -1.0, 1.0))))
    base_z = float(data.xpos[pm.root_body][2])
    mujoco.mj_subtreeVel(model, data)
    com = data.subtree_com[pm.root_body].copy()
    comdot = data.subtree_linvel[pm.root_body]
    height = max(com[2] - 0.5 * (soles[0][2, 3] + soles[1][2, 3]), 1e-3)
    g = max(-float(model.opt.gravity[2]), 1e-9)
    cp = com[:2] + comdot[:2] / math.sqrt(g / height)
    cp_out = max(0.0, -polygon_margin(polygon, cp))
    fall = pm.config.fall
    reason = ""
    held = ref.base_z if base_z_held is None else base_z_held
    if held - base_z > fall.base_drop_m:
        reason = (f"base {1e3 * (held - base_z):.0f} mm below " + ("its start height" if base_z_held is None else
                  "where its joints hold it on its feet") + f" (> {1e3 * fall.base_drop_m:.0f})")
    elif tilt > fall.tilt_deg:
        reason = f"base tilted {tilt:.1f} deg (> {fall.tilt_deg:g})"
    elif cp_out > fall.capture_point_out_m:
        reason = (f"capture point {1e3 * cp_out:.0f} mm outside the support polygon "
                  f"(> {1e3 * fall.capture_point_out_m:.0f})")
    return ContactMetrics(
        foot_force_n=(fsum[0], fsum[1]), foot_cop=foot_cop, cop=cop, support_polygon=polygon, cop_margin_m=margin,
        sole_slip_m=slip, base_tilt_deg=tilt, base_height_m=base_z, com=com, capture_point=cp,
        capture_point_out_m=cp_out, hand_force_n={s: float(np.linalg.norm(f)) for s, f in hand.items()},
        fallen=bool(reason), fall_reason=reason)


__all__ = ["LOADED_N", "ContactMetrics", "StandReference", "contact_metrics", "convex_hull", "polygon_margin",
           "sole_poses", "stand_reference"]
