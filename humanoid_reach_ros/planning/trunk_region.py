"""Where the trunk can be, from the robot: the goal sampler's trunk heights and pitches,
and a geometric bound that proves a target out of reach.

The paper samples the trunk height ``z_t`` and orientation ``rpy_t`` of ``q_goal`` but does
not say from which ranges. Constant ranges tuned to one scene miss low and high targets,
so the ranges here come from the robot and from the target:

* **What the legs allow** (:class:`TrunkRegion`): a grid over trunk height x pitch at the
  stance of the :class:`~humanoid_reach_ros.planning.projector.Projector` (roll and yaw 0,
  the horizontal position from ``COG_approx``, lines 2-4 of Algorithm 1), each cell kept
  when both legs' closed-form IK succeeds at its centre. The grid spans the heights the
  legs' chain lengths allow (soles up to ``|t0| + l1 + l2 + |te|``) and the pitches of
  ``pitch_span`` (our choice: -0.3 to 0.9 rad, leaning back a little to folded well
  forward); the legs' IK and joint limits decide within it.
* **What the target needs** (:meth:`TrunkRegion.for_target`): a cell is kept when some
  shoulder position it allows (yaw across its range) is within the arm's reach
  ``l1 + l2 + |te|`` of the target region, horizontally and vertically: a low target gets
  a low trunk, a high one a high trunk, a far one a forward lean. Simplification, named:
  the band is computed at roll 0 with a 2 cm slack, and each cell is tested at its centre;
  the projector still decides every sample exactly. When no cell passes (the target is
  farther than that band test allows but not provably out of reach) every leg-feasible
  cell is sampled.
* **Proof of "out of reach"** (:meth:`TrunkRegion.out_of_reach`): the trunk origin is at
  most ``R_leg`` above the soles (the legs' chain length), its orientation within the
  roll, pitch and yaw ranges the planner searches, its horizontal position set by
  ``COG_approx`` (``p_t = R_t v + COG_approx``); the shoulder is at ``R_t u`` from it and
  the hand within ``l1 + l2 + |te|`` of the shoulder (the closed form's reach condition).
  For a 7-joint arm the shoulder is the subchain's centre (joint 2), which joint 1 carries
  on a circle, and the reach the subchain's (``GeneralLimb.reach_centres``): measuring
  from joint 1's origin instead would credit the hand with the circle's radius in every
  direction (Talos: 0.884 m from joint 1's origin against 0.740 m from a joint-2 centre
  0.047 m above it), too loose to rule out a valve 2.25 m up that no posture reaches.
  A region farther than that from every such shoulder position, for every arm allowed,
  has no goal posture in the planner's search space whatever the sampler would try: the
  planner answers ``TARGET_OUT_OF_REACH`` at once instead of spending the budget. The
  bound ignores joint limits, orientation and collisions, so a target it cannot rule out
  may still have no goal (``NO_GOAL_FOUND`` when the budget runs out).

No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numba as nb
import numpy as np

from humanoid_reach_ros.codes import ARMS
from humanoid_reach_ros.planning.projector import rpy_into
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion, rpy_matrix

BAND_SLACK_M = 0.02     # vertical slack of the target band (roll, cell size)
PROOF_STEP_RAD = 0.05   # roll x pitch grid of the out-of-reach proof (and joint 1 of a 7-joint arm)
PROOF_REFINE = 5        # cells whose bound the grid's slack spoils are searched again this many times finer


@dataclass(frozen=True, eq=False)
class ArmReach:
    """What decides whether an arm may reach a hand pose from a trunk pose: the shoulder
    centre ``shoulder`` (trunk frame), the wrist centre ``w = p_e - R_e Re^T te`` of a hand
    pose, and the closed form's reach ``|shoulder - w| <= l1 + l2`` (``wrist_reach``)."""

    shoulder: np.ndarray
    Re: np.ndarray
    te: np.ndarray
    wrist_reach: float


@dataclass(frozen=True, eq=False)
class TrunkSampler:
    """Uniform over grid cells (``z_cells``, ``pitch_cells`` centres, size ``dz`` x
    ``dpitch``), roll and yaw uniform in their ranges. ``narrowed``: the cells were
    narrowed to the target (False: all leg-feasible cells).

    :meth:`sample_for` conditions the draw on the hand poses (``arms``, ``v``, ``cog_xy``
    give the geometry): ``candidates`` trunk draws per hand pose, the first whose shoulder
    reaches the pose's wrist centre kept. Our simplification of the paper's independent
    uniform ``q_goal`` draw, named: it only skips trunk draws Algorithm 1 would reject at
    the arm IK (the reach test is the closed form's own), so every goal it yields is one
    the plain draw could have yielded, at a far higher rate for low, high or far targets.
    """

    z_cells: np.ndarray
    pitch_cells: np.ndarray
    dz: float
    dpitch: float
    roll: tuple[float, float]
    yaw: tuple[float, float]
    narrowed: bool = True
    arms: dict | None = None        # arm name -> ArmReach
    v: np.ndarray | None = None     # COG_approx -> trunk origin, trunk frame
    cog_xy: np.ndarray | None = None
    candidates: int = 8
    order: np.ndarray | None = None  # cells nearest the start first (see :meth:`near`)
    first_fraction: float = 0.25
    #: 4-D cells (the reach map's inverse, planning/reach_map.py): roll and yaw per cell (cell
    #: sizes ``droll``, ``dyaw``) instead of uniform over ``roll`` / ``yaw``, and the map's
    #: proposals of whole goal samples (``PoseProposals``: :meth:`sample_poses`)
    roll_cells: np.ndarray | None = None
    yaw_cells: np.ndarray | None = None
    droll: float = 0.0
    dyaw: float = 0.0
    proposals: object | None = None

    def near(self, z: float, pitch: float, z_weight: float = 2.0, pitch_weight: float = 1.0,
             first: np.ndarray | None = None) -> "TrunkSampler":
        """The same cells, drawn nearest the trunk pose (``z``, ``pitch``) first: after ``b``
        batches without a goal (``sample_for``'s ``batch``), draws come from the nearest
        ``first_fraction * 2**b`` of the cells (all after two dry batches with 0.25),
        distance ``z_weight |dz| + pitch_weight |dpitch|`` (the planner's metric). The
        search starts where the robot stands and moves toward what the target needs only
        when it must: reachable targets get goals, and so paths, close to the start; hard
        ones get every cell within a few batches. ``first`` (bool per cell): those cells come
        first (each group nearest first): the reach map's cells deep inside the reachable set."""
        d = z_weight * np.abs(self.z_cells - z) + pitch_weight * np.abs(self.pitch_cells - pitch)
        if first is not None:
            return replace(self, order=np.lexsort((d, ~np.asarray(first, bool))))
        return replace(self, order=np.argsort(d, kind="stable"))

    def _cells(self, batch: int) -> np.ndarray:
        if self.order is None:
            return np.arange(len(self.z_cells))
        m = len(self.order)
        take = m if batch >= 30 else min(m, max(1, int(math.ceil(m * self.first_fraction * 2.0 ** batch))))
        return self.order[:take]

    def sample(self, rng: np.random.Generator, n: int, batch: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """z_t (n,), rpy_t (n, 3) = (roll, pitch, yaw)."""
        cells = self._cells(batch)
        k = cells[rng.integers(0, len(cells), size=n)]
        jitter = rng.uniform(-0.5, 0.5, size=(n, 2))
        z = self.z_cells[k] + jitter[:, 0] * self.dz
        pitch = self.pitch_cells[k] + jitter[:, 1] * self.dpitch
        if self.roll_cells is None:
            roll = rng.uniform(self.roll[0], self.roll[1], size=n)
            yaw = rng.uniform(self.yaw[0], self.yaw[1], size=n)
        else:
            ry = rng.uniform(-0.5, 0.5, size=(n, 2))
            roll = self.roll_cells[k] + ry[:, 0] * self.droll
            yaw = self.yaw_cells[k] + ry[:, 1] * self.dyaw
        return z, np.stack([roll, pitch, yaw], axis=1)

    def sample_for(self, rng: np.random.Generator, p_e: np.ndarray, R_e: np.ndarray,
                   arm: str = "auto", batch: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """z_t (n,), rpy_t (n, 3) for hand poses ``p_e`` (n, 3), ``R_e`` (n, 3, 3): per pose
        the first of ``candidates`` draws from which ``arm`` ("auto": either) reaches the
        wrist centre (the first draw when none does; Algorithm 1 then rejects it)."""
        n, k = len(p_e), self.candidates
        z, rpy = self.sample(rng, n * k, batch)
        if self.arms is None or k <= 1:
            return z[:n], rpy[:n]
        arms = [self.arms[a] for a in _arms(arm)]
        pick = np.empty(n, np.int64)
        _first_reaching(z, rpy, np.ascontiguousarray(p_e, dtype=float), np.ascontiguousarray(R_e, dtype=float),
                        self.v, self.cog_xy, np.array([g.shoulder for g in arms]), np.array([g.Re for g in arms]),
                        np.array([g.te for g in arms]), np.array([g.wrist_reach ** 2 for g in arms]), k, pick)
        return z[pick], rpy[pick]

    def sample_poses(self, rng: np.random.Generator, region: WorkspaceGoalRegion, n: int, arm: str = "auto",
                     batch: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``n`` whole goal samples ``(p_e, R_e, z_t, rpy_t)`` from the reach map (``proposals``):
        per sample ``candidates`` trunk draws and hand positions from ``region``, the one whose
        map proposal (a stored hand orientation in the region) comes from the voxel holding the
        most orientations (the first of those: deep inside the reachable set rather than at its
        border); a plain region draw and the first trunk draw when no proposal fits."""
        k = self.candidates
        z, rpy = self.sample(rng, n * k, batch)
        p_e, R_e = region.sample(rng, n * k)
        R_p, ok, held = self.proposals.propose(rng, region, z, rpy, p_e, _arms(arm))
        score = np.where(ok, held, -1).reshape(k, n)
        has = score.max(axis=0) >= 0
        pick = np.where(has, np.argmax(score, axis=0) * n + np.arange(n), np.arange(n))
        R_out = np.where(has[:, None, None], R_p[pick], R_e[:n])
        return p_e[pick], R_out, z[pick], rpy[pick]

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.z_cells.min() - self.dz / 2), float(self.z_cells.max() + self.dz / 2)

    @property
    def pitch_range(self) -> tuple[float, float]:
        return float(self.pitch_cells.min() - self.dpitch / 2), float(self.pitch_cells.max() + self.dpitch / 2)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of (z_t, roll, pitch, yaw): the trunk part of the planning space."""
        (z0, z1), (p0, p1) = self.z_range, self.pitch_range
        return (np.array([z0, self.roll[0], p0, self.yaw[0]]), np.array([z1, self.roll[1], p1, self.yaw[1]]))

    def describe(self) -> str:
        (z0, z1), (p0, p1) = self.z_range, self.pitch_range
        what = "cells" if self.roll_cells is None else "cells of the reach map's inverse"
        return f"trunk z {z0:.2f}-{z1:.2f} m, pitch {p0:.2f}-{p1:.2f} rad ({len(self.z_cells)} {what})"


class TrunkRegion:
    """Leg-feasible trunk heights x pitches of a projector's stance (module doc).

    ``z_span`` / ``pitch_span``: the grid's extent (``None`` z span: from the lowest sole to
    the legs' chain length above the highest); ``roll`` / ``yaw``: sampled uniformly;
    ``dz`` [m] / ``dpitch`` [rad]: cell size; ``candidates``: trunk draws per hand pose in
    :meth:`TrunkSampler.sample_for`. ValueError when no cell is leg-feasible.
    """

    def __init__(self, projector, z_span: tuple[float, float] | None = None,
                 pitch_span: tuple[float, float] = (-0.3, 0.9), roll: tuple[float, float] = (-0.1, 0.1),
                 yaw: tuple[float, float] = (-0.4, 0.4), dz: float = 0.01, dpitch: float = 0.05,
                 candidates: int = 8) -> None:
        for name, r in (("pitch_span", pitch_span), ("roll", roll), ("yaw", yaw)) + (
                (("z_span", z_span),) if z_span is not None else ()):
            if not (len(r) == 2 and all(math.isfinite(x) for x in r) and r[0] <= r[1]):
                raise ValueError(f"TrunkRegion.{name}: need finite lo <= hi, got {r}")
        if not (dz > 0 and dpitch > 0):
            raise ValueError(f"TrunkRegion: cell sizes must be > 0, got dz={dz}, dpitch={dpitch}")
        self.projector = projector
        ik = projector.ik
        soles = [projector.feet[leg][0] for leg in ("right_leg", "left_leg")]
        #: longest trunk-origin -> sole distance of each leg's chain
        self.leg_reach = {leg: _chain_reach(ik[leg]) for leg in ("right_leg", "left_leg")}
        self.trunk_z_max = min(float(s[2]) + self.leg_reach[leg] for s, leg in zip(soles, self.leg_reach))
        if z_span is None:
            z_span = (min(float(s[2]) for s in soles), self.trunk_z_max)
        self.z_span, self.pitch_span = tuple(map(float, z_span)), tuple(map(float, pitch_span))
        self.roll, self.yaw = tuple(map(float, roll)), tuple(map(float, yaw))
        self.dz, self.dpitch = float(dz), float(dpitch)
        self.candidates = int(candidates)
        zs = _cells(*self.z_span, self.dz)
        ps = _cells(*self.pitch_span, self.dpitch)
        Z, P = np.meshgrid(zs, ps, indexing="ij")
        self.z_grid, self.pitch_grid = Z.ravel(), P.ravel()
        self.pitches = ps
        na = projector.arm_dof["right"]
        q_plan = np.zeros((len(self.z_grid), na + 4))
        q_plan[:, :na] = projector.q_ref[projector.cols["right_arm"]]
        q_plan[:, na] = self.z_grid
        q_plan[:, na + 2] = self.pitch_grid
        res = projector.project_plan_config(q_plan, "right")
        self.feasible = res.ok.copy()
        # the grid's leg solutions start a numerical leg's IK near its answer (Projector.set_leg_seeds)
        Qg = np.where(res.ok[:, None], res.q, np.nan).reshape(len(zs), len(ps), -1)
        projector.set_leg_seeds(zs, ps, Qg)
        if not self.feasible.any():
            raise ValueError(f"TrunkRegion: the legs' IK admits no trunk height in {self.z_span} m at pitch "
                             f"{self.pitch_span} rad on this stance")
        #: per arm: trunk -> shoulder centre (trunk frame) and the hand's reach from it
        self.shoulder = {}
        self.arm_reach = {}
        self.arms = {}
        #: per arm: the proof's centres (K, 3) in the trunk frame, their slack [m] and the hand's reach from them
        self.centres = {}
        for arm in ARMS:
            lk = ik[f"{arm}_arm"]
            self.shoulder[arm] = projector.chest_p_in_trunk + projector.chest_R_in_trunk @ lk.t0
            self.arm_reach[arm] = _chain_reach(lk, with_root=False)
            self.arms[arm] = ArmReach(self.shoulder[arm], np.array(lk.Re, float), np.array(lk.te, float),
                                      float(lk.l1 + lk.l2) + 1e-3)
            # the proof's tight form (the limb protocol's reach_centres): a 7-joint arm's centre
            # moves on a circle, which ``shoulder`` + ``arm_reach`` (widened by the circle's radius
            # in every direction) covers loosely; a 6-joint arm's is ``shoulder`` and ``arm_reach`` itself
            pts, arc, reach = lk.reach_centres(PROOF_STEP_RAD)
            self.centres[arm] = (np.array([projector.chest_p_in_trunk + projector.chest_R_in_trunk @ p for p in pts]),
                                 float(arc), float(reach + np.linalg.norm(lk.te)) + 1e-3)
        self.cog_xy = np.array(projector.cog_approx_xy, float)
        self.v = np.array(projector.v, float)

    # ------------------------------------------------------------ the robot's ranges
    def all_cells(self) -> TrunkSampler:
        return self._sampler(self.feasible, False)

    def _sampler(self, cells: np.ndarray, narrowed: bool) -> TrunkSampler:
        return TrunkSampler(self.z_grid[cells], self.pitch_grid[cells], self.dz, self.dpitch, self.roll, self.yaw,
                            narrowed, self.arms, self.v, self.cog_xy, self.candidates)

    def from_cells(self, cells: np.ndarray, droll: float, dyaw: float, proposals, candidates: int) -> TrunkSampler:
        """A sampler over 4-D cells (M, 4) = (z, roll, pitch, yaw) centres of sizes ``dz`` x
        ``droll`` x ``dpitch`` x ``dyaw`` (the reach map's inverse at a target), its goal
        samples proposed by ``proposals`` (``PoseProposals``), ``candidates`` per sample."""
        return TrunkSampler(cells[:, 0].copy(), cells[:, 2].copy(), self.dz, self.dpitch, self.roll, self.yaw, True,
                            self.arms, self.v, self.cog_xy, int(candidates), roll_cells=cells[:, 1].copy(),
                            yaw_cells=cells[:, 3].copy(), droll=float(droll), dyaw=float(dyaw), proposals=proposals)

    def describe(self) -> str:
        s = self.all_cells()
        return f"legs allow {s.describe()} at roll/yaw 0 ({int(self.feasible.sum())} of {len(self.feasible)} cells)"

    # ------------------------------------------------------------ the target's band
    def for_target(self, region: WorkspaceGoalRegion, arm: str = "auto") -> TrunkSampler:
        """The leg-feasible cells from which ``arm`` ("auto": either) may reach ``region``."""
        centre, half, z_lo, z_hi, half_xy = _region_extent(region)
        keep = np.zeros(len(self.z_grid), bool)
        yaws = np.linspace(self.yaw[0], self.yaw[1], 9)
        for a in _arms(arm):
            u = self.shoulder[a]
            w = self.v + u                    # COG_approx -> shoulder, trunk frame
            L = self.arm_reach[a]
            for pitch in self.pitches:
                cp, sp = math.cos(pitch), math.sin(pitch)
                wx = cp * w[0] + sp * w[2]    # (Ry(pitch) w)_x
                uz = -sp * u[0] + cp * u[2]   # (Ry(pitch) u)_z: shoulder height above the trunk origin
                sx = self.cog_xy[0] + np.cos(yaws) * wx - np.sin(yaws) * w[1]
                sy = self.cog_xy[1] + np.sin(yaws) * wx + np.cos(yaws) * w[1]
                d = max(0.0, float(np.min(np.hypot(sx - centre[0], sy - centre[1]))) - half_xy)
                if d > L:
                    continue
                reach_z = math.sqrt(L * L - d * d) + BAND_SLACK_M
                lo, hi = z_lo - reach_z - uz, z_hi + reach_z - uz
                keep |= ((self.pitch_grid == pitch) & (self.z_grid >= lo - self.dz / 2)
                         & (self.z_grid <= hi + self.dz / 2))
        keep &= self.feasible
        if not keep.any():
            return self.all_cells()
        return self._sampler(keep, True)

    # ------------------------------------------------------------ the proof
    def out_of_reach(self, region: WorkspaceGoalRegion, arm: str = "auto") -> str | None:
        """A message when no allowed arm can reach ``region`` from any trunk pose searched
        (module doc), else None. Conservative: None does not mean reachable.

        The trunk poses: height up to the legs' chain length above the soles (at any
        height below), orientation within the roll, pitch and yaw ranges searched. Yaw is
        exact (it turns the shoulder on a horizontal circle about ``COG_approx`` and leaves
        its height alone: the nearest point of that arc is closed-form); roll and pitch are
        gridded at ``PROOF_STEP_RAD``, the centres of a 7-joint arm taken every
        ``PROOF_STEP_RAD`` of joint 1 (``GeneralLimb.reach_centres``), and what the shoulder
        may move between grid points is subtracted. The grid cells whose bound that slack
        spoils are searched again ``PROOF_REFINE`` times finer (near the bound only)."""
        centre, half, _, _, _ = _region_extent(region)
        s_r, s_p = _step(self.roll, PROOF_STEP_RAD), _step(self.pitch_span, PROOF_STEP_RAD)
        R, P = (g.ravel() for g in np.meshgrid(_grid(self.roll, PROOF_STEP_RAD),
                                               _grid(self.pitch_span, PROOF_STEP_RAD), indexing="ij"))
        off = (np.arange(PROOF_REFINE) - (PROOF_REFINE - 1) / 2) / PROOF_REFINE   # sub-points of a cell
        reasons = []
        for a in _arms(arm):
            U, arc, reach = self.centres[a]
            need = reach + half
            m, k = (g.ravel() for g in np.meshgrid(np.arange(len(R)), np.arange(len(U)), indexing="ij"))
            d = self._shoulder_distance(R[m], P[m], U[k], centre)
            if d.min() <= need:   # a searched trunk pose puts the hand there: no proof
                return None
            low = d - self._slack(U, arc, (s_r + s_p) / 2)
            spoilt = low <= need
            if spoilt.any():      # those cells again, finer: roll x pitch sub-points, each cell's extent
                rr = np.clip(R[m[spoilt]][:, None, None] + off[None, :, None] * s_r, *self.roll)
                pp = np.clip(P[m[spoilt]][:, None, None] + off[None, None, :] * s_p, *self.pitch_span)
                rr, pp = (g.ravel() for g in np.broadcast_arrays(rr, pp))
                fine = self._shoulder_distance(rr, pp, np.repeat(U[k[spoilt]], PROOF_REFINE ** 2, axis=0), centre)
                low = np.concatenate([low[~spoilt],
                                      fine - self._slack(U, arc, (s_r + s_p) / (2 * PROOF_REFINE))])
            bound = float(low.min())
            gap = bound - need
            if gap <= 0:
                return None
            reasons.append(f"hand {reach:.3f} m from a shoulder at best {_m(bound)} m away, {_m(gap)} m short")
        arms = _arms(arm)
        reasons = ([f"{' and '.join(arms)} {reasons[0].replace('hand', 'hands', 1) if len(arms) > 1 else reasons[0]}"]
                   if len(set(reasons)) == 1 else [f"{a} {r}" for a, r in zip(arms, reasons)])
        return (f"{'; '.join(reasons)}; searched: trunk up to {self.trunk_z_max:.2f} m, roll "
                f"{self.roll[0]:.2f}..{self.roll[1]:.2f}, pitch {self.pitch_span[0]:.2f}..{self.pitch_span[1]:.2f}, "
                f"yaw {self.yaw[0]:.2f}..{self.yaw[1]:.2f} rad")

    def _shoulder_distance(self, roll: np.ndarray, pitch: np.ndarray, U: np.ndarray, centre: np.ndarray) -> np.ndarray:
        """(N,) distance from ``centre`` to the nearest shoulder centre ``U`` (N, 3) (trunk frame)
        of a trunk at ``roll``, ``pitch`` (N,), any yaw searched and any height up to the legs'."""
        Rrp = rpy_matrix(np.stack([roll, pitch, np.zeros(len(roll))], axis=1))   # Ry(pitch) Rx(roll)
        Pxy = np.einsum("nij,nj->ni", Rrp[:, :2], self.v + U)    # COG_approx -> centre at yaw 0, horizontal
        uz = np.einsum("nj,nj->n", Rrp[:, 2], U)                  # centre height above the trunk origin
        dh = _arc_distance(Pxy, centre[:2] - self.cog_xy, self.yaw)
        dv = np.maximum(0.0, np.maximum(centre[2] - (self.trunk_z_max + uz), (self.z_span[0] + uz) - centre[2]))
        return np.hypot(dh, dv)

    def _slack(self, U: np.ndarray, arc: float, eps: float) -> float:
        """How far the distance may drop between grid points: roll and pitch within ``eps``
        (summed) of a grid point move a centre by at most ``eps`` times its lever (horizontally
        ``|v + U|``, vertically ``|U|``; a centre up to ``arc`` off its point, longer by that),
        the distance is 1-Lipschitz in both, and the centre is within ``arc`` of a point."""
        lever_h = float(np.linalg.norm(self.v + U, axis=1).max()) + arc
        lever_v = float(np.linalg.norm(U, axis=1).max()) + arc
        return eps * math.hypot(lever_h, lever_v) + arc


def _m(v: float) -> str:
    """A length for a message: mm precision, 3 significant digits beyond 10 km (``--target 1e308``)."""
    return f"{v:.3f}" if abs(v) < 1e4 else f"{v:.3g}"


def _arc_distance(P: np.ndarray, T: np.ndarray, yaw: tuple[float, float]) -> np.ndarray:
    """Distance from the point ``T`` (2,) to the arc ``Rz(psi) P`` (P: (..., 2)), psi in
    ``yaw``: ``|T - Rz(psi) P|`` grows with the angle between ``Rz(psi) P`` and ``T``, so it is
    ``| |T| - |P| |`` when the arc passes ``T``'s direction, else the nearer end's."""
    rho = np.hypot(P[..., 0], P[..., 1])
    ahead = np.mod(math.atan2(T[1], T[0]) - np.arctan2(P[..., 1], P[..., 0]) - yaw[0], 2 * math.pi)
    ends = []
    for psi in yaw:
        c, s = math.cos(psi), math.sin(psi)
        ends.append(np.hypot(T[0] - (c * P[..., 0] - s * P[..., 1]), T[1] - (s * P[..., 0] + c * P[..., 1])))
    return np.where(ahead <= yaw[1] - yaw[0], np.abs(math.hypot(T[0], T[1]) - rho), np.minimum(*ends))


@nb.njit(cache=True, nogil=False, fastmath=False)
def _first_reaching(z, rpy, p_e, R_e, v, cog_xy, shoulder, Re, te, reach2, k, pick):
    """:meth:`TrunkSampler.sample_for`'s choice, compiled: for hand pose ``i`` (of n), the
    first candidate ``j * n + i`` (j < k) whose trunk ``(z, rpy)`` puts some arm's shoulder
    within ``sqrt(reach2)`` of the pose's wrist centre ``p_e - R_e Re^T te``; ``i`` if none.
    The trunk pose is Algorithm 1's lines 2-4 (``p_t = R_t v + COG_approx``, height z)."""
    n = p_e.shape[0]
    n_arms = shoulder.shape[0]
    w = np.empty((n_arms, 3))
    R = np.empty((3, 3))
    for i in range(n):
        for a in range(n_arms):     # wrist centres of pose i
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    m = 0.0        # (R_e Re^T)[r, c]
                    for t in range(3):
                        m += R_e[i, r, t] * Re[a, c, t]
                    acc += m * te[a, c]
                w[a, r] = p_e[i, r] - acc
        pick[i] = i
        for j in range(k):
            c_ = j * n + i
            rpy_into(R, rpy[c_, 0], rpy[c_, 1], rpy[c_, 2])
            found = False
            for a in range(n_arms):
                d2 = 0.0
                for r in range(3):
                    s_r = R[r, 0] * (v[0] + shoulder[a, 0]) + R[r, 1] * (v[1] + shoulder[a, 1]) \
                        + R[r, 2] * (v[2] + shoulder[a, 2])
                    if r < 2:
                        s_r += cog_xy[r]
                    else:   # height: z_t + (R_t u)_z
                        s_r = z[c_] + R[2, 0] * shoulder[a, 0] + R[2, 1] * shoulder[a, 1] + R[2, 2] * shoulder[a, 2]
                    d2 += (s_r - w[a, r]) ** 2
                if d2 <= reach2[a]:
                    found = True
                    break
            if found:
                pick[i] = c_
                break


def _arms(arm: str) -> tuple[str, ...]:
    if arm in (None, "", "auto"):
        return ARMS
    if arm not in ARMS:
        raise ValueError(f"arm must be 'auto', 'right' or 'left', got {arm!r}")
    return (arm,)


def _step(r: tuple[float, float], step: float) -> float:
    n = max(1, int(math.ceil((r[1] - r[0]) / step - 1e-9)))
    return (r[1] - r[0]) / n


def _grid(r: tuple[float, float], step: float) -> np.ndarray:
    """Points of ``r`` at most ``step`` apart, both ends included."""
    n = max(1, int(math.ceil((r[1] - r[0]) / step - 1e-9)))
    return np.linspace(r[0], r[1], n + 1)


def _cells(lo: float, hi: float, step: float) -> np.ndarray:
    n = max(1, int(math.ceil((hi - lo) / step - 1e-9)))
    return lo + (np.arange(n) + 0.5) * ((hi - lo) / n if hi > lo else 0.0)


def _chain_reach(lk, with_root: bool = True) -> float:
    """Longest root -> tip distance of a closed-form limb: ``|t0|`` (root -> first axes'
    intersection, when ``with_root``) + ``l1 + l2`` (the two links between the
    intersections: the reach condition of the closed form) + ``|te|`` (wrist -> tip),
    plus 1 mm for the solver's tolerances."""
    r = float(lk.l1 + lk.l2 + np.linalg.norm(lk.te)) + 1e-3
    return r + (float(np.linalg.norm(lk.t0)) if with_root else 0.0)


def _region_extent(region: WorkspaceGoalRegion):
    """Centre (3,), half diagonal, world z range and horizontal half extent of the region's
    position box."""
    lo, hi = np.asarray(region.lower[:3], float), np.asarray(region.upper[:3], float)
    mid = (lo + hi) / 2
    centre = np.asarray(region.target_p, float) + np.asarray(region.target_R, float) @ mid
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    world = corners @ np.asarray(region.target_R, float).T + np.asarray(region.target_p, float)
    half = float(np.linalg.norm(hi - lo) / 2)
    half_xy = float(np.max(np.hypot(world[:, 0] - centre[0], world[:, 1] - centre[1])))
    return centre, half, float(world[:, 2].min()), float(world[:, 2].max()), half_xy


__all__ = ["TrunkRegion", "TrunkSampler"]
