"""The problem every side of bench/peers solves: one robot, one scene, one WGR, one seed set.

Imports only numpy/pinocchio/yaml and the project's algorithm modules (no rclpy), so it
runs in the project venv and in ``.venv-peers``. ``write_problem`` exports what a peer
needs as files in a work directory (the peers may live in venvs without the project):

* ``problem.npz``: joint names and limits, half-sitting ``q_start``, stance sole poses,
  support polygon, the WGR samples (hand target poses) and random seed configurations
  for the numerical projections (goal peers), the goals of this project for the path
  peers (added by :func:`add_goals`);
* ``hrp2_capsules.urdf``: config/robots/hrp2/hrp2.urdf with the project's collision shapes
  (config/robots/hrp2/collision.yaml) as URDF ``<collision>`` elements (a capsule =
  a cylinder + two end spheres: URDF has no capsule) -- for HPP;
* ``hrp2_capsules.srdf``: every link pair whose shapes are NOT a self-collision pair
  of the project's model is disabled, so HPP checks the same self pairs;
* ``scene.urdf``: the plant scene's primitives without the floor and the valve group
  (boxes, finite cylinders, spheres) as one fixed body -- for HPP;
* ``problem.json``: the scalar settings.

Validity of a goal (:func:`goal_validity`), the same for every side: joint limits, both
soles at their stance poses, the hand (right or left) in the WGR, static stability
(exact COM horizontally inside the support polygon = the feet's bounding box) and
collision-free by the project's checker (:class:`RobotCollision`, sphere tree of the
2 cm voxel map without the valve).
"""
from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from humanoid_reach_ros.geometry.distance import RobotCollision  # noqa: E402
from humanoid_reach_ros.planning.projector import Projector  # noqa: E402
from humanoid_reach_ros.planning.reach import PlannerParams, ReachPlanner  # noqa: E402
from humanoid_reach_ros.planning.wgr import valve_region  # noqa: E402
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel  # noqa: E402
from humanoid_reach_ros.sim.scene import load_scene  # noqa: E402

SEED = 20120514
SCENE = "scenes/plant.yaml"
EXCLUDE_GROUPS = ("valve",)
HANDS = ("r_hand_ee", "l_hand_ee")
SOLES = ("r_sole", "l_sole")
# tolerances of the common validity check
POS_TOL_M = 1e-3
ROT_TOL_RAD = 1e-3
LIMIT_TOL_RAD = 1e-6


@dataclass
class Problem:
    robot: RobotModel
    planner: ReachPlanner          # map set: its .collision is the project's checker
    projector: Projector
    region: object                 # WorkspaceGoalRegion
    scene: object
    voxels: np.ndarray
    params: PlannerParams
    support_lo: np.ndarray
    support_hi: np.ndarray

    @property
    def collision(self) -> RobotCollision:
        return self.planner.collision

    @property
    def q_start(self) -> np.ndarray:
        return self.robot.half_sitting()


def support_polygon(robot: RobotModel, collision_model) -> tuple[np.ndarray, np.ndarray]:
    """xy bounding box (lo, hi) of the foot shapes at the stance (as bench/goal_sampling.py)."""
    P0, P1, R = collision_model.world_shapes(robot.half_sitting())
    feet = [i for i, n in enumerate(collision_model.names) if "foot" in n]
    pts = np.concatenate([P0[feet, :2], P1[feet, :2]])
    r = R[feet].max()
    return pts.min(0) - r, pts.max(0) + r


def build_problem(params: PlannerParams | None = None) -> Problem:
    params = PlannerParams() if params is None else params
    scene = load_scene(SCENE)
    voxels = scene.voxelize(params.resolution_m, exclude_groups=EXCLUDE_GROUPS)
    rp = ReachPlanner(params=params)
    rp.set_map(voxels)
    lo, hi = support_polygon(rp.robot, rp.collision_model)
    return Problem(rp.robot, rp, rp.projector, valve_region(scene.target.pose), scene, voxels, params, lo, hi)


# ------------------------------------------------------------------ seeds
def goal_seeds(prob: Problem, n: int, seed: int = SEED) -> dict:
    """Inputs of the numerical projections, shared by every goal peer: ``targets`` (n, 4, 4)
    hand poses sampled in the WGR, ``q_seed`` (n, nq) random configurations (joints
    uniform within their limits, base at the half-sitting base pose)."""
    rng = np.random.default_rng(seed)
    p, R = prob.region.sample(rng, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    q0 = prob.q_start
    Q = np.tile(q0, (n, 1))
    Q[:, N_BASE_Q:] = prob.robot.lower + rng.random((n, prob.robot.n_joints)) * (prob.robot.upper - prob.robot.lower)
    return {"targets": T, "q_seed": Q}


# ------------------------------------------------------------------ validity
def goal_validity(prob: Problem, Q: np.ndarray) -> dict:
    """The common goal check of (a) on configurations (n, nq) in the project's layout.

    Returns ``ok`` (n,) and the count of each failure (a configuration may fail several)
    and ``time_s`` (the check's own time, charged to the side that produced ``Q``)."""
    t0 = time.perf_counter()
    robot, m = prob.robot, prob.robot.model
    d = m.createData()
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    n = len(Q)
    fails = {"not_finite": 0, "joint_limits": 0, "feet": 0, "hand_not_in_wgr": 0, "static_stability": 0,
             "collision": 0}
    ok = np.zeros(n, bool)
    soles = robot.stance_soles
    fid_s = [robot.frame_id(f) for f in SOLES]
    fid_h = [robot.frame_id(f) for f in HANDS]
    reg = prob.region
    for k, q in enumerate(Q):
        if not np.all(np.isfinite(q)):
            fails["not_finite"] += 1
            continue
        q = q.copy()
        q[3:7] /= np.linalg.norm(q[3:7])
        good = True
        j = q[N_BASE_Q:]
        if np.any(j < robot.lower - LIMIT_TOL_RAD) or np.any(j > robot.upper + LIMIT_TOL_RAD):
            fails["joint_limits"] += 1
            good = False
        pin.framesForwardKinematics(m, d, q)
        for f, s in zip(fid_s, soles):
            e = pin.log6(d.oMf[f].actInv(s)).vector
            if np.linalg.norm(e[:3]) > POS_TOL_M or np.linalg.norm(e[3:]) > ROT_TOL_RAD:
                fails["feet"] += 1
                good = False
                break
        in_wgr = False
        for f in fid_h:
            M = d.oMf[f]
            if np.linalg.norm(M.translation - reg.target_p) <= POS_TOL_M and reg.contains(
                    reg.target_p, M.rotation, tol=ROT_TOL_RAD):
                in_wgr = True
                break
        if not in_wgr:
            fails["hand_not_in_wgr"] += 1
            good = False
        com = pin.centerOfMass(m, d, q, False)
        if np.any(com[:2] < prob.support_lo) or np.any(com[:2] > prob.support_hi):
            fails["static_stability"] += 1
            good = False
        if good:
            if not prob.collision.check(q):
                fails["collision"] += 1
                good = False
        ok[k] = good
    return {"ok": ok, "n": n, "n_valid": int(ok.sum()), "failures": fails, "time_s": time.perf_counter() - t0}


# ------------------------------------------------------------------ files for the peers
def _capsule_xml(p0, p1, r) -> str:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    out = []
    for c in (p0, p1):
        out.append(f'<collision><origin xyz="{c[0]:.9g} {c[1]:.9g} {c[2]:.9g}" rpy="0 0 0"/>'
                   f'<geometry><sphere radius="{r:.9g}"/></geometry></collision>')
    L = float(np.linalg.norm(p1 - p0))
    if L > 1e-9:
        out.append(_cylinder_xml(p0, p1, r))
    return "".join(out)


def _cylinder_xml(p0, p1, r) -> str:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    c = 0.5 * (p0 + p1)
    L = float(np.linalg.norm(p1 - p0))
    z = (p1 - p0) / L
    R = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), z).toRotationMatrix()
    rpy = pin.rpy.matrixToRpy(R)
    return (f'<collision><origin xyz="{c[0]:.9g} {c[1]:.9g} {c[2]:.9g}" rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/>'
            f'<geometry><cylinder radius="{r:.9g}" length="{L:.9g}"/></geometry></collision>')


def robot_urdf_with_capsules(prob: Problem) -> str:
    """The robot URDF with the project's shapes (padded radii) as collision elements."""
    import xml.etree.ElementTree as ET

    cm = prob.planner.collision_model
    root = ET.fromstring(prob.robot.urdf_xml)
    per_link: dict[str, list[str]] = {}
    for s, _name in enumerate(cm.names):
        link = cm.links[int(cm.shape_link[s])]
        per_link.setdefault(link, []).append(_capsule_xml(cm.p0_local[s], cm.p1_local[s], float(cm.radii[s])))
    # shapes are expressed in the link *frame*; pinocchio frames of links coincide with the URDF links
    for link in root.findall("link"):
        for c in link.findall("collision"):
            link.remove(c)
        for xml in per_link.pop(link.get("name"), []):
            for el in ET.fromstring(f"<x>{xml}</x>"):
                link.append(el)
    if per_link:
        raise ValueError(f"collision shapes on frames that are not URDF links: {sorted(per_link)}")
    return ET.tostring(root, encoding="unicode")


def robot_srdf(prob: Problem) -> str:
    """SRDF disabling every link pair that carries no self-collision pair of the project."""
    cm = prob.planner.collision_model
    link_of = [cm.links[int(cm.shape_link[s])] for s in range(cm.n_shapes)]
    checked = {frozenset((link_of[i], link_of[j])) for i, j in cm.pair_index}
    links = [ln.get("name") for ln in __import__("xml.etree.ElementTree", fromlist=["x"]).fromstring(
        prob.robot.urdf_xml).findall("link")]
    rows = []
    for a in range(len(links)):
        for b in range(a + 1, len(links)):
            if frozenset((links[a], links[b])) not in checked:
                rows.append(f'<disable_collisions link1={quoteattr(links[a])} link2={quoteattr(links[b])} '
                            f'reason="not a self pair of hrp2_collision.yaml"/>')
    return '<?xml version="1.0"?>\n<robot name="hrp2">\n' + "\n".join(rows) + "\n</robot>\n"


def scene_primitives(prob: Problem) -> list:
    return [p for p in prob.scene.select(include_floor=False, exclude_groups=EXCLUDE_GROUPS)]


def scene_urdf(prob: Problem) -> str:
    """The scene's obstacles (no floor, no valve) as one fixed link of collision elements."""
    parts = []
    for p in scene_primitives(prob):
        if p.kind == "box":
            c, rpy, s = np.asarray(p.center, float), np.asarray(p.rpy, float), np.asarray(p.size, float)
            parts.append(f'<collision name={quoteattr(p.name)}><origin xyz="{c[0]:.9g} {c[1]:.9g} {c[2]:.9g}" '
                         f'rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/><geometry><box size="{s[0]:.9g} '
                         f'{s[1]:.9g} {s[2]:.9g}"/></geometry></collision>')
        elif p.kind == "cylinder":
            parts.append(_cylinder_xml(p.p0, p.p1, float(p.radius)))
        elif p.kind == "sphere":
            c = np.asarray(p.center, float)
            parts.append(f'<collision><origin xyz="{c[0]:.9g} {c[1]:.9g} {c[2]:.9g}"/><geometry><sphere '
                         f'radius="{float(p.radius):.9g}"/></geometry></collision>')
        else:
            raise ValueError(f"scene primitive {p.name!r} of type {p.kind} has no URDF form here")
    return ('<?xml version="1.0"?>\n<robot name="plant"><link name="scene">' + "".join(parts)
            + "</link></robot>\n")


def write_problem(prob: Problem, workdir: Path, n_seeds: int, seed: int = SEED) -> dict:
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    r = prob.robot
    seeds = goal_seeds(prob, n_seeds, seed)
    soles = r.stance_soles
    np.savez(workdir / "problem.npz", joint_names=np.array(r.joint_names), lower=r.lower, upper=r.upper,
             q_start=prob.q_start, sole_r=soles[0].homogeneous, sole_l=soles[1].homogeneous,
             support_lo=prob.support_lo, support_hi=prob.support_hi, cog_target_xy=prob.projector.cog_approx_xy,
             region_p=prob.region.target_p, region_R=prob.region.target_R, region_lower=prob.region.lower,
             region_upper=prob.region.upper, targets=seeds["targets"], q_seed=seeds["q_seed"])
    (workdir / "hrp2_capsules.urdf").write_text(robot_urdf_with_capsules(prob))
    (workdir / "hrp2_capsules.srdf").write_text(robot_srdf(prob))
    (workdir / "scene.urdf").write_text(scene_urdf(prob))
    meta = {"urdf": str(r.urdf_path), "urdf_capsules": str(workdir / "hrp2_capsules.urdf"),
            "srdf_capsules": str(workdir / "hrp2_capsules.srdf"), "scene_urdf": str(workdir / "scene.urdf"),
            "n_seeds": n_seeds, "seed": seed, "hands": HANDS, "soles": SOLES,
            "edge_resolution": prob.params.edge_resolution, "rrt_step": prob.params.rrt_step,
            "weights": prob.params.weights.tolist(), "time_budget_s": prob.params.time_budget_s,
            "pos_tol_m": POS_TOL_M, "rot_tol_rad": ROT_TOL_RAD,
            "locked_joints": locked_joint_names(prob)}
    (workdir / "problem.json").write_text(json.dumps(meta, indent=1))
    return meta


def locked_joint_names(prob: Problem) -> dict:
    """Joints Algorithm 1 does not move (chest, head, grippers) and the arms, by name."""
    r = prob.robot
    arm = {a: [r.joint_names[i] for i in r.limbs[f"{a}_arm"].joint_index] for a in ("right", "left")}
    legs = [r.joint_names[i] for limb in ("right_leg", "left_leg") for i in r.limbs[limb].joint_index]
    fixed = [n for n in r.joint_names if n not in legs and n not in arm["right"] and n not in arm["left"]]
    return {"fixed": fixed, "right_arm": arm["right"], "left_arm": arm["left"], "legs": legs}


def add_goals(workdir: Path, goals_q: np.ndarray, goals_arm: np.ndarray, goals_plan: np.ndarray,
              start_plan: dict) -> None:
    """The goals of the path problems (b): full configurations, arm codes, q_plan rows."""
    np.savez(Path(workdir) / "goals.npz", q=goals_q, arm=goals_arm, plan=goals_plan,
             start_plan_right=start_plan["right"], start_plan_left=start_plan["left"])


def rad(x: float) -> float:
    return math.radians(x)
