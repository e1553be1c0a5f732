"""Goal posture sampling (Kanehiro et al., Sec. III-B, Table I).

Repeat until ``n_goals`` goals (or the time budget is spent): sample ``q_goal = (p_e,
rpy_e, z_t, rpy_t)`` -- the hand pose uniformly in the WGR (eq. 3), the trunk height
and orientation uniformly in :class:`TrunkSampling` -- project it with Algorithm 1
(:class:`~humanoid_reach_ros.planning.projector.Projector`), and keep it when it is
collision-free (:class:`~humanoid_reach_ros.geometry.distance.RobotCollision`).

Samples are drawn and projected ``batch_size`` at a time (numpy); only the IK-valid
ones are collision-checked. The result is a deterministic function of the rng state:
goals are taken in sample order and the statistics cover exactly the samples up to
the last goal taken (a batch's tail past it is discarded, not counted).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from humanoid_reach_ros.geometry.distance import RobotCollision
from humanoid_reach_ros.codes import ARM_LEFT, ARM_RIGHT
from humanoid_reach_ros.planning.projector import Projector
from humanoid_reach_ros.planning.wgr import WorkspaceGoalRegion
from humanoid_reach_ros.robot.model import RobotModel

if TYPE_CHECKING:
    from humanoid_reach_ros.planning.trunk_region import TrunkSampler


DRY_SAMPLES = 512   # a TrunkSampler's cells widen after this many samples without a goal
PROJECT_CHUNK = 16  # samples of a batch projected at a time (at least twice the goals still needed)


@dataclass(frozen=True)
class TrunkSampling:
    """Uniform ranges of the trunk (waist) height and orientation in ``q_goal``.

    These ranges are ours: the paper does not give them. Defaults: ``z_t`` in
    [0.55, 0.78] m (the half-sitting waist is at 0.739 m; the legs' reach ends near
    0.80 m), roll +-0.1, pitch [-0.1, 0.6] (leaning forward), yaw +-0.4 rad.
    """

    z_t: tuple[float, float] = (0.55, 0.78)
    roll: tuple[float, float] = (-0.1, 0.1)
    pitch: tuple[float, float] = (-0.1, 0.6)
    yaw: tuple[float, float] = (-0.4, 0.4)

    def __post_init__(self) -> None:
        for name in ("z_t", "roll", "pitch", "yaw"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"TrunkSampling.{name}: need finite lo <= hi, got {(lo, hi)}")

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """z_t (n,), rpy_t (n, 3)."""
        lo = np.array([self.z_t[0], self.roll[0], self.pitch[0], self.yaw[0]])
        hi = np.array([self.z_t[1], self.roll[1], self.pitch[1], self.yaw[1]])
        x = rng.uniform(lo, hi, size=(n, 4))
        return x[:, 0], x[:, 1:]


@dataclass
class GoalSamplingStats:
    """The quantities of Table I (plus a few of ours).

    ``total_time_s`` / ``time_per_goal_s``: wall time of :func:`sample_goals`;
    ``n_samples``: q_goal samples drawn (up to the last goal taken);
    ``collision_checks``: configurations collision-checked (the IK-valid samples) and
    ``collision_time_s`` their checking time (FK of the capsules apart, in
    ``collision_fk_time_s``); ``arm_used``: goals per arm; ``ik_failures``: per limb,
    counted as in Algorithm 1's order.
    """

    n_goals: int = 0
    n_samples: int = 0
    total_time_s: float = 0.0
    collision_checks: int = 0
    collision_time_s: float = 0.0
    collision_fk_time_s: float = 0.0
    n_in_collision: int = 0
    arm_used: dict = field(default_factory=lambda: {"right": 0, "left": 0})
    ik_failures: dict = field(default_factory=lambda: {"right_arm": 0, "left_arm": 0, "right_leg": 0,
                                                       "left_leg": 0})
    timed_out: bool = False

    @property
    def time_per_goal_s(self) -> float:
        return self.total_time_s / self.n_goals if self.n_goals else float("inf")

    @property
    def collision_time_per_call_s(self) -> float:
        return self.collision_time_s / self.collision_checks if self.collision_checks else 0.0

    @property
    def collision_time_share(self) -> float:
        return self.collision_time_s / self.total_time_s if self.total_time_s else 0.0

    def as_dict(self) -> dict:
        return {
            "n_goals": self.n_goals,
            "time_per_goal_ms": 1e3 * self.time_per_goal_s,
            "total_time_s": self.total_time_s,
            "n_samples": self.n_samples,
            "collision_checks": self.collision_checks,
            "collision_time_per_call_ms": 1e3 * self.collision_time_per_call_s,
            "collision_time_share_pct": 100.0 * self.collision_time_share,
            "collision_fk_time_per_call_ms": (1e3 * self.collision_fk_time_s / self.collision_checks
                                              if self.collision_checks else 0.0),
            "n_in_collision": self.n_in_collision,
            "arm_used": dict(self.arm_used),
            "ik_failures": dict(self.ik_failures),
            "timed_out": self.timed_out,
        }


@dataclass(frozen=True, eq=False)
class Goals:
    """Goal postures ``q`` (G, nq), ``arm`` (G,) int8 arm codes (codes.ARM_RIGHT / ARM_LEFT), the hand poses
    sampled for them ``p_e`` (G, 3), ``R_e`` (G, 3, 3), and ``stats``."""

    q: np.ndarray
    arm: np.ndarray
    p_e: np.ndarray
    R_e: np.ndarray
    stats: GoalSamplingStats

    def __len__(self) -> int:
        return len(self.q)


def sample_goals(region: WorkspaceGoalRegion, n_goals: int, robot: RobotModel, collision: RobotCollision,
                 rng: np.random.Generator, arm: str = "auto", trunk: "TrunkSampling | TrunkSampler | None" = None,
                 time_budget_s: float = float("inf"), batch_size: int = 512,
                 projector: Projector | None = None, max_samples: int | None = None) -> Goals:
    """Sample up to ``n_goals`` collision-free goal postures for ``region``.

    ``arm``: ``"auto"`` (right arm first, then left; Algorithm 1), ``"right"`` or
    ``"left"``. Stops after ``time_budget_s`` (``stats.timed_out``) with the goals
    found so far, or once ``max_samples`` samples are drawn (both also
    ``stats.timed_out``; with neither, an infeasible region loops forever).
    ``projector`` may be shared between calls (it is built otherwise). ``trunk``: a
    :class:`TrunkSampling` box (the paper's independent uniform draw; the default) or a
    :class:`~humanoid_reach_ros.planning.trunk_region.TrunkSampler` (the planner's: ranges
    from the robot and the target, draws conditioned on the hand pose; with the reach map's
    ``proposals``, whole samples the map proposes: ``TrunkSampler.sample_poses``).
    """
    if n_goals < 0 or batch_size < 1:
        raise ValueError(f"need n_goals >= 0 and batch_size >= 1, got {n_goals}, {batch_size}")
    t_start = time.perf_counter()
    trunk = TrunkSampling() if trunk is None else trunk
    projector = Projector(robot) if projector is None else projector
    stats = GoalSamplingStats()
    qs, arms, ps, Rs = [], [], [], []
    c0 = collision.counters
    chk0, ct0, cf0 = c0.checks, c0.check_time_s, c0.fk_time_s
    dry = 0     # samples of batches that gave no goal: a TrunkSampler widens its cells with each
    #             DRY_SAMPLES of them (one default batch), whatever the batch size
    while len(qs) < n_goals:
        if time.perf_counter() - t_start > time_budget_s or (max_samples is not None
                                                            and stats.n_samples >= max_samples):
            stats.timed_out = True
            break
        if getattr(trunk, "proposals", None) is not None:   # the reach map proposes whole samples
            p_e, R_e, z_t, rpy_t = trunk.sample_poses(rng, region, batch_size, arm, batch=dry // DRY_SAMPLES)
        else:
            p_e, R_e = region.sample(rng, batch_size)
            if hasattr(trunk, "sample_for"):   # TrunkSampler: trunk draws conditioned on the hand poses
                z_t, rpy_t = trunk.sample_for(rng, p_e, R_e, arm, batch=dry // DRY_SAMPLES)
            else:
                z_t, rpy_t = trunk.sample(rng, batch_size)
        need = n_goals - len(qs)
        # the batch is drawn whole (the same draws whatever the chunking) but projected and
        # checked in chunks, in order (twice the goals still needed, at least PROJECT_CHUNK
        # samples, each chunk twice the last), until it holds the goals needed: the same goals
        # and counts as projecting it whole, without the IK of the samples past the last goal
        # taken (a failed numerical limb IK costs ~0.5 ms: every start runs)
        chunk = max(PROJECT_CHUNK, 2 * need)
        take, n_in_coll, n_checked = [], 0, 0
        end = batch_size
        s1 = 0
        while s1 < batch_size:
            s0, s1 = s1, min(s1 + chunk, batch_size)
            chunk *= 2
            res = projector.project_config(p_e[s0:s1], R_e[s0:s1], z_t[s0:s1], rpy_t[s0:s1], arm=arm)
            idx = np.flatnonzero(res.ok)
            free = collision.check_batch(res.q[idx]) if idx.size else np.zeros(0, bool)
            got = idx[free][:need - len(take)]
            # the samples this chunk accounts for: all, or up to the last goal taken
            stop = len(take) + len(got) == need
            e = int(got[-1]) + 1 if stop else s1 - s0
            in_prefix = idx < e
            n_checked += int(np.count_nonzero(in_prefix))
            n_in_coll += int(np.count_nonzero(in_prefix & ~free))
            for k, v in res.failures_upto(e).items():
                stats.ik_failures[k] += v
            for k in got:
                qs.append(res.q[k])
                arms.append(res.arm[k])
                ps.append(p_e[s0 + k])
                Rs.append(R_e[s0 + k])
            take.extend((s0 + got).tolist())
            if stop:
                end = s0 + e
                break
        dry += batch_size if len(take) == 0 else 0
        stats.n_samples += end
        stats.collision_checks += n_checked
        stats.n_in_collision += n_in_coll
    c1 = collision.counters
    checked = c1.checks - chk0
    scale = stats.collision_checks / checked if checked else 0.0   # time of the counted checks only
    stats.collision_time_s = (c1.check_time_s - ct0) * scale
    stats.collision_fk_time_s = (c1.fk_time_s - cf0) * scale
    arm_arr = np.array(arms, np.int8)
    stats.n_goals = len(qs)
    stats.arm_used = {"right": int(np.count_nonzero(arm_arr == ARM_RIGHT)),
                      "left": int(np.count_nonzero(arm_arr == ARM_LEFT))}
    stats.total_time_s = time.perf_counter() - t_start
    nq = robot.model.nq
    return Goals(np.array(qs).reshape(-1, nq), arm_arr, np.array(ps).reshape(-1, 3), np.array(Rs).reshape(-1, 3, 3),
                 stats)


def cog_errors(goals_q: np.ndarray, robot: RobotModel, projector: Projector) -> np.ndarray:
    """Exact COG minus ``COG_approx``, horizontal (G, 2) [m] (Fig. 4)."""
    out = np.empty((len(goals_q), 2))
    approx = projector.cog_approx(goals_q)
    for k, q in enumerate(goals_q):
        out[k] = robot.com(q)[:2] - approx[k, :2]
    return out


__all__ = ["TrunkSampling", "GoalSamplingStats", "Goals", "sample_goals", "cog_errors"]
