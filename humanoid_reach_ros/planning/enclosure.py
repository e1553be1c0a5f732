"""A collision proof at the target: the target lies in a pocket of the map closed all round
(issue 35, item 2: a fast, honest "no" where no reach bound decides).

The argument (a simplification, named as such, of the free-space connectivity arguments behind
disconnection proofs in motion planning -- e.g. Basch et al. 2001, "Disconnection proofs for
motion planning"; here one point-to-point connectivity test on a grid, no configuration space):

1. **The arm is a thick curve.** The polyline from the hand's tip frame through the origins of
   the arm's joints, last to first, and on from the first joint's origin towards the middle of
   the arm root's (the chest's) thickest shape, is rigid piecewise: each of its segments is
   fixed in one body. :class:`ArmTube` checks once per robot, in each body's own frame, that
   every point of the polyline but its first ``lead`` metres (from the tip) lies ``radius`` deep
   inside a collision shape: one of that body's, one of its parent's or child's turned about the
   joint between them over that joint's limits (every ``Q_STEP``, less the point's motion between
   two samples), or a sphere centred on a joint origin every joint in between shares (sampled
   every ``STEP_M``, less half a step); the segment into the chest is kept as far as it keeps
   80 % of the arm's depth. So wherever a point of it is, an environment sphere whose centre comes
   within ``radius`` plus the sphere's own radius of it collides with that shape.
2. **Blocked cells.** A grid of cells around the target (:func:`cell_size`: the map's resolution,
   or half of it for a thin tube): a cell is blocked when its eight corners lie strictly within
   ``radius + sphere radius`` of one sphere centre of the planner's collision map (the occupied
   voxels, without the target's object): any point of the polyline in a blocked cell collides.
3. **The pocket.** The cells within ``lead + extent`` (the region's position box) of the target
   hold the polyline's start. A fill from those that are not blocked, through cells sharing a
   face, an edge or a corner (26 neighbours: every continuous curve from cell to cell goes
   through such a sequence), stays inside the box around the target (``BOX_M``): the pocket is
   closed. If it reaches the box's border there is no proof.
4. **The far end is outside.** The polyline's far end, in the chest, lies at every trunk posture
   searched (the trunk cells of the reach map's inverse, or the same grid without a map:
   :func:`trunk_cells`; each cell's motion counted, cells that come close split in 16 up to
   ``SHOULDER_LEVELS`` times) farther than a cell's half diagonal from every pocket cell.

Then every continuous curve from the tip to the chest leaves the pocket through a blocked cell:
every posture with the hand in the region collides. ``NO_GOAL_FOUND`` is answered at once, with
the pocket in the message. Sound for the map the planner checks against and for the postures it
searches (Algorithm 1's: the chest joints at the reference, the trunk in the leg-feasible cells);
a target whose pocket is open, or a chest that might be inside it, is left to the goal sampler
as before.

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import pinocchio as pin

from humanoid_reach_ros.planning.projector import rpy_into

STEP_M = 0.002          # the polyline's samples for the depth check
BOX_M = 0.30            # half size of the box the fill may not leave [m]
MAX_LEAD_M = 0.10       # a tip this far from the tube's start: no proof for that arm
Q_STEP = 0.02           # a neighbour body's joint sampled this finely [rad]
MAX_POCKET = 1_000_000  # a pocket of more cells: no proof
SHOULDER_LEVELS = 3     # trunk cells split in 16 this many times to keep the shoulder out of the pocket


@dataclass(frozen=True)
class ArmTube:
    """The arm's polyline (module doc, 1): ``radius`` [m] deep inside the arm's shapes from
    ``lead`` [m] (along it, from the tip) on; ``shoulder`` (3,): its far end in the arm's root
    link (past the first joint's origin, the middle of the root's thickest shape)."""

    arm: str
    radius: float
    lead: float
    shoulder: np.ndarray

    @classmethod
    def of(cls, robot, collision_model, arm: str) -> "ArmTube | None":
        """The tube of ``arm`` (None: no part of the polyline is inside the shapes). A point of a
        segment (fixed in joint ``j``'s body) counts as deep as the deepest of: ``j``'s body's
        shapes; its parent's and its child's, turned about the joint between them over that
        joint's limits (every ``Q_STEP`` rad, less the point's motion between two of them); a
        sphere of the chain centred on a joint origin every joint between them shares (no
        rotation of those joints moves it)."""
        limb = robot.limbs[f"{arm}_arm"]
        model = robot.model
        data = model.createData()
        q = pin.neutral(model)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        jids = [model.getJointId(j) for j in limb.joints]
        origin = {j: np.array(data.oMi[j].translation) for j in jids}
        axis = {j: data.oMi[j].rotation @ np.asarray(data.joints[j].S, float).reshape(6, -1)[3:, 0] for j in jids}
        if not all(abs(np.linalg.norm(a) - 1.0) < 1e-6 for a in axis.values()):
            return None                                  # not a chain of revolute joints
        lo = {j: float(model.lowerPositionLimit[model.joints[j].idx_q]) for j in jids}
        hi = {j: float(model.upperPositionLimit[model.joints[j].idx_q]) for j in jids}
        cm = collision_model
        parent = np.array([model.frames[int(f)].parentJoint for f in cm.frame_ids])[cm.shape_link]
        P0, P1, _ = cm.world_shapes(q)
        radii = np.asarray(cm.radii, float)
        root_joint = model.frames[model.getFrameId(limb.root)].parentJoint
        chain = [root_joint] + jids                     # bodies, root first
        tip = np.array(data.oMf[model.getFrameId(limb.tip)].translation)
        points = [tip] + [origin[j] for j in reversed(jids)]
        bodies = list(reversed(jids))                   # segment k lies in this joint's body
        mine = np.flatnonzero(parent == root_joint)     # on into the trunk: the root's thickest shape
        if len(mine):
            i = mine[np.argmax(radii[mine])]
            points.append((P0[i] + P1[i]) / 2)
            bodies.append(root_joint)

        def depth_static(pts, body):
            d = np.full(len(pts), -np.inf)
            for i in np.flatnonzero(parent == body):
                d = np.maximum(d, radii[i] - _point_segment(pts, P0[i], P1[i]))
            return d

        def depth_turned(pts, body, j):
            """Shapes of ``body`` turned about joint ``j`` (relative to the points) over its limits."""
            shapes = np.flatnonzero(parent == body)
            if not len(shapes):
                return np.full(len(pts), -np.inf)
            n = max(2, int(math.ceil((hi[j] - lo[j]) / Q_STEP)) + 1)
            qs = np.linspace(lo[j], hi[j], n)
            lever = np.linalg.norm(np.cross(pts - origin[j], axis[j]), axis=1)
            worst = np.full(len(pts), np.inf)
            for qv in qs:
                Rq = pin.exp3(axis[j] * qv)
                x = (pts - origin[j]) @ Rq + origin[j]     # the points turned by -q: the shapes by +q
                d = np.full(len(pts), -np.inf)
                for i in shapes:
                    d = np.maximum(d, radii[i] - _point_segment(x, P0[i], P1[i]))
                worst = np.minimum(worst, d)
            return worst - lever * (qs[1] - qs[0]) / 2

        def depth_spheres(pts, k):
            """Spheres centred on a joint origin shared by every joint between them and body k."""
            d = np.full(len(pts), -np.inf)
            pos = chain.index(bodies[k])
            for i in np.flatnonzero(np.linalg.norm(P1 - P0, axis=1) == 0):
                if parent[i] not in chain:
                    continue
                a, b = sorted((chain.index(parent[i]), pos))
                between = [origin[j] for j in chain[a + 1:b + 1] if j in origin]
                if between and all(np.linalg.norm(o - P0[i]) < 1e-9 for o in between):
                    d = np.maximum(d, radii[i] - np.linalg.norm(pts - P0[i], axis=1))
            return d

        depth, along = [], []
        s0 = 0.0
        for k in range(len(points) - 1):
            a, b = points[k], points[k + 1]
            length = float(np.linalg.norm(b - a))
            if length < 1e-9 and k > 0:
                continue                                 # one point, an end of its neighbours'
            n = max(2, int(math.ceil(length / STEP_M)) + 1)
            t = np.linspace(0.0, 1.0, n)
            pts = a + t[:, None] * (b - a)
            body = bodies[k]
            pos = chain.index(body)
            d = np.maximum(depth_static(pts, body), depth_spheres(pts, k))
            if pos > 0:
                d = np.maximum(d, depth_turned(pts, chain[pos - 1], body))      # the parent about joint `body`
            if pos + 1 < len(chain):
                d = np.maximum(d, depth_turned(pts, chain[pos + 1], chain[pos + 1]))   # the child about its joint
            depth.append(d - length / (n - 1) / 2)
            along.append(s0 + t * length)
            s0 += length
        trunk_depth = depth.pop() if len(mine) else np.zeros(0)   # the segment into the trunk, apart
        along.pop() if len(mine) else None
        depth, along = np.concatenate(depth), np.concatenate(along)
        best = None
        for lead in np.arange(0.0, MAX_LEAD_M + 1e-9, 0.01):      # the lead that leaves the deepest tube
            r = float(depth[along >= lead].min())
            if r > 0 and (best is None or r > best[0] + 1e-3):
                best = (r, float(lead))
        if best is None:
            return None
        end = points[-2] if len(mine) else points[-1]
        if len(trunk_depth):            # as far into the trunk as keeps 80 % of that depth
            k = len(trunk_depth) if trunk_depth.min() >= 0.8 * best[0] else int(np.argmax(trunk_depth < 0.8 * best[0]))
            if k > 1:
                end = points[-2] + (points[-1] - points[-2]) * (k - 1) / (len(trunk_depth) - 1)
                best = (min(best[0], float(trunk_depth[:k].min())), best[1])
        oMr = data.oMf[model.getFrameId(limb.root)]
        shoulder = oMr.rotation.T @ (end - oMr.translation)
        return cls(arm, best[0], best[1], shoulder)


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = float(ab @ ab)
    t = np.zeros(len(p)) if den <= 0 else np.clip((p - a) @ ab / den, 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


@nb.njit(cache=True)
def _blocked(centres, radii, lo, h, n, reach_extra, out) -> None:
    """Marks the cells (grid ``lo``, ``h``, ``n`` per axis) whose eight corners all lie within
    ``radius + reach_extra`` of one sphere (less 1e-6 m: strictly inside)."""
    for s in range(centres.shape[0]):
        R = radii[s] + reach_extra - 1e-6
        if R <= 0.0:
            continue
        c0, c1, c2 = centres[s, 0], centres[s, 1], centres[s, 2]
        i0 = max(0, int(math.floor((c0 - R - lo[0]) / h)))
        i1 = min(n - 1, int(math.floor((c0 + R - lo[0]) / h)))
        j0 = max(0, int(math.floor((c1 - R - lo[1]) / h)))
        j1 = min(n - 1, int(math.floor((c1 + R - lo[1]) / h)))
        k0 = max(0, int(math.floor((c2 - R - lo[2]) / h)))
        k1 = min(n - 1, int(math.floor((c2 + R - lo[2]) / h)))
        for i in range(i0, i1 + 1):
            x = max(abs(lo[0] + i * h - c0), abs(lo[0] + (i + 1) * h - c0))
            for j in range(j0, j1 + 1):
                y = max(abs(lo[1] + j * h - c1), abs(lo[1] + (j + 1) * h - c1))
                for k in range(k0, k1 + 1):
                    z = max(abs(lo[2] + k * h - c2), abs(lo[2] + (k + 1) * h - c2))
                    if x * x + y * y + z * z < R * R:
                        out[i, j, k] = True


@nb.njit(cache=True)
def _fill(blocked, seeds, pocket) -> bool:
    """Fill of the free cells from ``seeds`` (K, 3) through their 26 neighbours into ``pocket``
    (depth first: in open space it runs straight to the border); False as soon as it reaches the
    grid's border (open) or passes ``MAX_POCKET`` cells."""
    n = blocked.shape[0]
    stack = np.empty((min(n * n * n, MAX_POCKET), 3), np.int64)
    top = 0
    for s in range(seeds.shape[0]):
        i, j, k = seeds[s, 0], seeds[s, 1], seeds[s, 2]
        if not blocked[i, j, k] and not pocket[i, j, k]:
            pocket[i, j, k] = True
            stack[top, 0], stack[top, 1], stack[top, 2] = i, j, k
            top += 1
    while top > 0:
        top -= 1
        i, j, k = stack[top, 0], stack[top, 1], stack[top, 2]
        if i == 0 or j == 0 or k == 0 or i == n - 1 or j == n - 1 or k == n - 1:
            return False
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for dk in range(-1, 2):
                    a, b, c = i + di, j + dj, k + dk
                    if not blocked[a, b, c] and not pocket[a, b, c]:
                        if top == stack.shape[0]:
                            return False
                        pocket[a, b, c] = True
                        stack[top, 0], stack[top, 1], stack[top, 2] = a, b, c
                        top += 1
    return True


@nb.njit(cache=True)
def _shoulder_clear(cells, half, v, cog_xy, s, lo, h, n, pocket, pmin, pmax, bad) -> None:
    """Is the shoulder (``s`` in the trunk frame) at each trunk cell (Algorithm 1's trunk pose at
    its centre, moving within it by ``dz + theta (|v| + |s|)``) farther than a cell's half
    diagonal from every pocket cell? ``bad[c]``: not shown (the pocket's cells near it looked up
    in ``pocket``, within its index box ``pmin..pmax``)."""
    for c in range(cells.shape[0]):
        bad[c] = _shoulder_near(cells[c], half, v, cog_xy, s, lo, h, n, pocket, pmin, pmax)


@nb.njit(cache=True)
def _shoulder_near(cell, half, v, cog_xy, s, lo, h, n, pocket, pmin, pmax) -> bool:
    R = np.empty((3, 3))
    theta = half[1] + half[2] + half[3]
    vn = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    sn = math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    reach = half[0] + theta * (vn + sn) + h * math.sqrt(3.0) / 2.0
    rpy_into(R, cell[1], cell[2], cell[3])
    x0 = R[0, 0] * (v[0] + s[0]) + R[0, 1] * (v[1] + s[1]) + R[0, 2] * (v[2] + s[2]) + cog_xy[0]
    x1 = R[1, 0] * (v[0] + s[0]) + R[1, 1] * (v[1] + s[1]) + R[1, 2] * (v[2] + s[2]) + cog_xy[1]
    x2 = cell[0] + R[2, 0] * s[0] + R[2, 1] * s[1] + R[2, 2] * s[2]
    i0 = max(pmin[0], int(math.floor((x0 - reach - lo[0]) / h)))
    i1 = min(pmax[0], int(math.floor((x0 + reach - lo[0]) / h)))
    j0 = max(pmin[1], int(math.floor((x1 - reach - lo[1]) / h)))
    j1 = min(pmax[1], int(math.floor((x1 + reach - lo[1]) / h)))
    k0 = max(pmin[2], int(math.floor((x2 - reach - lo[2]) / h)))
    k1 = min(pmax[2], int(math.floor((x2 + reach - lo[2]) / h)))
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                if pocket[i, j, k]:
                    d0 = lo[0] + (i + 0.5) * h - x0
                    d1 = lo[1] + (j + 0.5) * h - x1
                    d2 = lo[2] + (k + 0.5) * h - x2
                    if d0 * d0 + d1 * d1 + d2 * d2 <= reach * reach:
                        return True
    return False


@dataclass(frozen=True)
class Pocket:
    """A closed pocket around a target: its cells' count, box and the cell size."""

    cells: int
    lo: np.ndarray
    hi: np.ndarray
    cell_m: float

    def describe(self) -> str:
        return (f"a closed pocket of {self.cells} free cells of {100 * self.cell_m:.0f} cm, x "
                f"{self.lo[0]:.2f}..{self.hi[0]:.2f}, y {self.lo[1]:.2f}..{self.hi[1]:.2f}, z "
                f"{self.lo[2]:.2f}..{self.hi[2]:.2f} m")


def trunk_cells(region, step_rad: float) -> tuple:
    """``(cells (M, 4), half (4,), v, cog_xy, chest_p, chest_R)``: the balanced trunk manifold of a
    :class:`~humanoid_reach_ros.planning.trunk_region.TrunkRegion` gridded as the reach map's
    inverse grids it (its leg-feasible height x pitch cells x roll and yaw cells of ``step_rad``),
    for a planner without a reach map."""
    from humanoid_reach_ros.planning.reach_map import _cells

    pj = region.projector
    rolls, droll = _cells(region.roll, step_rad)
    yaws, dyaw = _cells(region.yaw, step_rad)
    zs, ps = region.z_grid[region.feasible], region.pitch_grid[region.feasible]
    Z, R_, Y = (g.ravel() for g in np.meshgrid(np.arange(len(zs)), np.arange(len(rolls)), np.arange(len(yaws)),
                                                indexing="ij"))
    cells = np.stack([zs[Z], rolls[R_], ps[Z], yaws[Y]], axis=1)
    half = np.array([region.dz / 2, droll / 2, region.dpitch / 2, dyaw / 2])
    return (cells, half, np.array(pj.v, float), np.array(pj.cog_approx_xy, float), np.array(pj.chest_p_in_trunk, float),
            np.array(pj.chest_R_in_trunk, float))


def cell_size(tubes, sphere_radius: float, resolution_m: float) -> float | None:
    """The fill's cell [m] for ``tubes``: the map's resolution where the thinnest tube plus a sphere
    blocks a cell and its face neighbours (``>= 1.6 h``), half of it where it blocks at least the
    cell (``>= 0.8 h``), else None: too thin a tube for the map to close a pocket around it."""
    R = min(t.radius for t in tubes) + float(sphere_radius)
    if R >= 1.6 * resolution_m:
        return float(resolution_m)
    if R >= 0.8 * resolution_m:
        return float(resolution_m) / 2
    return None


def enclosed(target: np.ndarray, extent: float, tubes, centres: np.ndarray, radii: np.ndarray,
             cell_m: float, trunk: tuple) -> Pocket | None:
    """The proof of the module doc for the arms of ``tubes`` (:class:`ArmTube`, one fill for all:
    the thinnest tube, the longest lead): the :class:`Pocket` that holds every hand position of
    the region (``target`` (3,), world, and the region's half diagonal ``extent``) and none of the
    tubes' far ends, or None (no proof). ``centres`` (N, 3) / ``radii`` (N,): the planner's
    environment spheres; ``trunk``: ``(cells (M, 4), half (4,), v, cog_xy, chest_p, chest_R)``: the
    trunk cells searched (:class:`~humanoid_reach_ros.planning.reach_map.InverseReach`'s)."""
    h = float(cell_m)
    n = int(math.ceil(2 * BOX_M / h))
    target = np.asarray(target, float)
    lo = target - n * h / 2
    radius = min(t.radius for t in tubes)
    lead = max(t.lead for t in tubes)
    centres = np.asarray(centres, float).reshape(-1, 3)
    radii = np.broadcast_to(np.asarray(radii, float), (len(centres),))
    near = np.all(np.abs(centres - target) <= n * h / 2 + radii[:, None] + radius, axis=1)
    blocked = np.zeros((n, n, n), bool)
    _blocked(np.ascontiguousarray(centres[near]), np.ascontiguousarray(radii[near]), lo, h, n, float(radius), blocked)
    r = lead + extent + h * math.sqrt(3.0) / 2
    m = int(math.ceil(r / h)) + 1
    c = np.floor((target - lo) / h).astype(np.int64)
    g = np.stack(np.meshgrid(*[np.arange(-m, m + 1)] * 3, indexing="ij"), -1).reshape(-1, 3) + c
    g = g[np.linalg.norm(lo + (g + 0.5) * h - target, axis=1) <= r]
    if np.any(g <= 0) or np.any(g >= n - 1):
        return None
    pocket = np.zeros_like(blocked)
    if not _fill(blocked, np.ascontiguousarray(g), pocket):
        return None
    idx = np.argwhere(pocket)
    if not len(idx):
        return Pocket(0, target, target, h)      # every cell the tube may start in is blocked
    pmin, pmax = idx.min(axis=0), idx.max(axis=0)
    cells0, half0, v, cog_xy, chest_p, chest_R = trunk
    v, cog_xy = np.asarray(v, float), np.asarray(cog_xy, float)
    offs = np.array(np.meshgrid(*[[-0.5, 0.5]] * 4, indexing="ij")).reshape(4, -1).T   # 16 sub-cells
    for tube in tubes:
        s = np.asarray(chest_p, float) + np.asarray(chest_R, float) @ tube.shoulder
        cells, half = np.ascontiguousarray(cells0, dtype=float), np.asarray(half0, float)
        for level in range(SHOULDER_LEVELS + 1):
            bad = np.zeros(len(cells), bool)
            _shoulder_clear(cells, half, v, cog_xy, s, lo, h, n, pocket, pmin, pmax, bad)
            if not bad.any():
                break
            if level == SHOULDER_LEVELS or bad.sum() > 4096:
                return None
            half = half / 2        # the cells the far end may be in the pocket from, split in 16
            cells = np.ascontiguousarray((cells[bad][:, None, :] + offs[None] * 2 * half).reshape(-1, 4))
    return Pocket(len(idx), lo + pmin * h, lo + (pmax + 1) * h, h)


__all__ = ["ArmTube", "Pocket", "enclosed", "cell_size", "trunk_cells", "BOX_M"]
