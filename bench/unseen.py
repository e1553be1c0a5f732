"""Issue 31's audit: plans of the RUNNING graph checked against the scene file's TRUE geometry,
in scenes with obstacles the head's scan cannot see.

**Scenes** (generated at run time into ``--out``/scenes/, one per seed, used for nothing else):
the robot's demo scene (``demo_scene`` of its description; the plant for HRP-2) plus hidden
primitives (group ``hidden``): two behind the back (a post, a rail, a box or a hoop), one
beside each hip (a box, a post or a ball), one under an arm (a ball, a box or a rail) and one
low behind the legs (a box on the floor, a rail or a ball), each of a random kind and size,
pushed along a random horizontal direction of its region until its exact clearance to the
robot's capsules in half-sitting is a drawn distance; the scene's six distances are spread
over [0.05, 0.30] m (stratified). Whether the scan saw them is measured, not assumed
(``hidden_seen_by_scan``: a hidden primitive with a /voxel_map voxel within 2 cm of its
surface after the scan).

**Targets**: ``--targets-per-scene`` random points all around the robot (azimuth uniform over
the full turn: in front, beside and behind; 0.25-0.75 m from the vertical through the stance
origin; 0.45-1.45 m high), each at least 0.20 m from every primitive of the scene (the
planner leaves the map's voxels within ``target_exclusion_radius_m`` = 0.15 m of a target
out: nearer ones would test that policy, not unseen space) and 0.10 m from the robot's body
in half-sitting. The region is ``reach_operator``'s default (the valve WGR of eq. 3 around the
point), the arm ``auto``.

**The graph's flow** per scene: a fresh graph (bench/session.py's ``Session``: bench/graph.py's
``Bench``, the six nodes as processes in an isolated domain, the planner on the MEASURED
/voxel_map, nothing from the scene file), one ``reach_operator --scan``, then per target
``reach_operator --target X Y Z --seed S --budget B`` without ``--execute``: the CLI's own
flow (``operator.session.OperatorSession`` on ``nodes.reach_operator.Operator``, in this
process), so a plan answered UNOBSERVED_SPACE gets up to 3 automatic looks (which move the
robot) and is planned again; the reach itself is never executed. Each /plan_reach response
is kept.

**The truth** (after the graph is stopped, so it takes none of the graph's CPU):

* every trajectory returned with SUCCESS is rebuilt (``SplineTrajectory`` through its samples,
  as the executor does) and its capsules (file radii, no padding) are checked at every sample
  and at >= 8 points between two (more where a shape's end moves > 1 cm) against every
  primitive of the scene file by exact signed distance (``testing/truth.py``): a negative
  distance is a plan through an obstacle (``plans_penetrating_true_obstacles``, with the
  deepest: depth [mm], primitive, shape, time);
* **feasible and observable** (the definition of this bench): a target is feasible and
  observable when a plan to it exists that stays out of the true obstacles and out of the space
  no sensor could show the robot. The oracle: ``ReachPlanner`` (config/reach_planner.yaml's
  parameters, the same seed and budget) from the same start posture (the measured joints at
  the target's first request) on the scene file's voxels (every primitive, the hidden ones
  included), with the space no reachable gaze sees as unobserved space to avoid (policy
  ``occupied``). That space: the ``CELL_M`` (4 cm) cells of ``OBSERVE_BOX`` whose centre no gaze
  from the first target's start sees (``GazeSolver.sees`` over a grid of chest 9 x 7 x neck
  10 x 10 postures within their limits), less the robot's own volume grown by ``BODY_MARGIN_M``
  = 3 cm (issue 31's policy: what the robot occupied is known free; the oracle's scene marks
  each target's start posture so, as the planner does); its outer layer goes to the oracle as
  the frontier (a plan cannot cross it, so it never enters that space). The stance zone is
  known free to the oracle too (``--stance``, by default the voxel mapper's
  ``stance_clearance_m``: the body at half-sitting grown by it, which the policy assumes the
  operator keeps clear). Oracle SUCCESS:
  feasible and observable; UNOBSERVED_SPACE: feasible only through unobservable space (the
  planner's own check on the true voxels alone); other codes: not feasible within the budget.
  Simplifications, named: the gaze grid, not ``GazeSolver.observable``'s search, decides (a
  point seen only between grid postures counts as unobservable: the oracle errs strict); the
  body and the environment occlude nothing (as ``GazeSolver``); one planner's sampling decides
  (an arm-only plan its trunk sampling misses is not found). A feasible and observable target
  is *reached* when the graph's final answer, after at most the operator's 3 looks, is SUCCESS
  and its plan penetrates nothing.

Every target counts in every denominator: a step that failed (an exception, a node that
died, no answer) is a target with no answer, missed; a SUCCESS whose trajectory could not be
checked counts as penetrating; a target whose truth could not be computed counts as feasible
and observable (and so, unless reached, missed).

Last line: one JSON object: ``unseen_plans`` (SUCCESS plans checked), ``plans_penetrating_true_obstacles``
(target 0) with ``worst_penetration`` and ``penetrating_cases``, split into
``penetrating_in_stance_zone`` (through a hidden obstacle the scene put nearer the body than the
stance zone's clearance: the scene broke the policy's declared assumption) and
``plans_penetrating_beyond_stance_zone``, ``unobservable_answers``
(final UNOBSERVABLE_SPACE), ``unobserved_answers`` (final UNOBSERVED_SPACE after the looks),
``feasible_observable_targets``, ``feasible_observable_success_rate`` (target >= 0.95),
``codes`` (final code per target), ``targets``, ``seeds``, ``wall_s``, ``commit``, ``machine``;
also ``starts_inside_true_obstacles``: targets whose start (the measured posture after the
earlier targets' looks, which execute) already lies inside a true obstacle.

Usage: ``python bench/unseen.py [--robot hrp2] [--seeds 1 2 3 4] [--targets-per-scene 50]
[--budget 3] [--body-margin 0.03] [--quick] [--out out/unseen] [--truth-only]``; ``--quick``: one scene, 20 targets;
``--truth-only``: no graph, the truth of an earlier run's records (``--out``) computed again.
"""
from __future__ import annotations

import argparse
import io
import json
import math
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "bench"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from humanoid_reach_ros.codes import ErrorCode, code_name  # noqa: E402

BUDGET_S = 3.0              # --budget of every plan, the graph's and the truth's
MAX_LOOKS = 3               # reach_operator's default --max-looks
HIDDEN_GROUP = "hidden"
DISTANCE_RANGE_M = (0.05, 0.30)     # clearance of a hidden primitive to the body in half-sitting
TARGET_CLEARANCE_M = 0.20           # a target this far from every primitive at least
TARGET_BODY_CLEARANCE_M = 0.10      # ... and from the robot's body in half-sitting
TARGET_RADIUS_M = (0.25, 0.75)      # from the vertical through the stance origin
TARGET_HEIGHT_M = (0.45, 1.45)
BODY_MARGIN_M = 0.03                # the robot's volume at the start, grown by this, is known free space


def stance_clearance_m() -> float:
    """The voxel mapper's ``stance_clearance_m`` (config/voxel_mapper.yaml): the space within it
    of the robot's shapes at its reference posture counts as observed free (the operator keeps
    it clear where the robot is placed: a named assumption of the policy)."""
    doc = yaml.safe_load((Path(__file__).resolve().parents[1] / "config/voxel_mapper.yaml").read_text())
    return float(doc["/**"]["ros__parameters"]["stance_clearance_m"])
CELL_M = 0.04                       # cells of the observability oracle [m]
OBSERVE_BOX = ((-1.2, -1.2, 0.0), (1.4, 1.2, 2.0))   # ... over this box [m, world]: everything the arms reach
SEEN_BY_MAP_M = 0.02                # a hidden primitive with a map voxel this near its surface was seen
TRUTH_EXTENT = ((-1.2, -1.2, 0.0), (1.5, 1.2, 2.1))
QUICK_TARGETS = 20
TARGETS = {"plans_penetrating_true_obstacles": ("==", 0), "feasible_observable_success_rate": (">=", 0.95)}

# region: (anchor lo, anchor hi) [m, world] inside the body, side: push direction yaw [deg] (the
# side's sign applies to beside/under), kinds
REGIONS: dict[str, dict[str, Any]] = {
    "behind_back": {"anchor": ((-0.10, -0.20, 0.90), (-0.05, 0.20, 1.35)), "yaw_deg": (150.0, 210.0),
                    "kinds": ("post", "rail", "box", "hoop")},
    "beside_hip": {"anchor": ((-0.05, 0.15, 0.55), (0.08, 0.20, 0.85)), "yaw_deg": (55.0, 125.0),
                   "kinds": ("box", "post", "ball")},
    "under_arm": {"anchor": ((-0.05, 0.20, 0.95), (0.03, 0.25, 1.15)), "yaw_deg": (80.0, 135.0),
                  "kinds": ("ball", "box", "rail")},
    "low_behind_legs": {"anchor": ((-0.05, -0.12, 0.10), (0.03, 0.12, 0.40)), "yaw_deg": (135.0, 225.0),
                        "kinds": ("floor_box", "rail", "ball")},
}
# the hidden primitives of a scene: (region, side) -- side +1 left, -1 right, 0 random
LAYOUT = (("behind_back", 0), ("behind_back", 0), ("beside_hip", 1), ("beside_hip", -1), ("under_arm", 0),
          ("low_behind_legs", 0))


# ---------------------------------------------------------------- scenes and targets
def _primitive(kind: str, name: str, c: np.ndarray, u: np.ndarray, rng: np.random.Generator) -> dict[str, Any]:
    """A hidden primitive of ``kind`` about ``c`` (world); ``u`` the horizontal push direction."""
    side = np.array([-u[1], u[0], 0.0])         # horizontal, across the push
    r3 = lambda v: [round(float(x), 4) for x in v]   # noqa: E731
    base = {"name": name, "group": HIDDEN_GROUP, "color": [0.3, 0.6, 0.3]}
    if kind == "post":
        return {**base, "type": "cylinder", "p0": r3([c[0], c[1], 0.0]), "p1": r3([c[0], c[1], 1.9]),
                "radius": round(float(rng.uniform(0.025, 0.06)), 4)}
    if kind == "rail":
        half = 0.5 * rng.uniform(0.4, 0.9)
        return {**base, "type": "cylinder", "p0": r3(c - half * side), "p1": r3(c + half * side),
                "radius": round(float(rng.uniform(0.015, 0.04)), 4)}
    if kind == "box":
        return {**base, "type": "box", "center": r3(c), "size": r3(rng.uniform(0.08, 0.25, 3)),
                "rpy": [0.0, 0.0, round(float(rng.uniform(-math.pi, math.pi)), 4)]}
    if kind == "floor_box":
        size = rng.uniform(0.10, 0.25, 3)
        size[2] = 2.0 * max(c[2], 0.05)
        return {**base, "type": "box", "center": r3([c[0], c[1], 0.5 * size[2]]), "size": r3(size),
                "rpy": [0.0, 0.0, round(float(rng.uniform(-math.pi, math.pi)), 4)]}
    if kind == "ball":
        return {**base, "type": "sphere", "center": r3(c), "radius": round(float(rng.uniform(0.04, 0.12)), 4)}
    if kind == "hoop":
        axis = u if rng.random() < 0.5 else np.array([0.0, 0.0, 1.0])
        return {**base, "type": "torus", "center": r3(c), "axis": r3(axis),
                "major_radius": round(float(rng.uniform(0.08, 0.15)), 4),
                "minor_radius": round(float(rng.uniform(0.01, 0.025)), 4)}
    raise ValueError(f"unknown hidden kind {kind!r}")


def body_capsules(robot, cm, joints: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The robot's capsules (file radii) at ``joints`` (default half-sitting), the waist on the feet."""
    j = robot.half_sitting_joints if joints is None else np.asarray(joints, float)
    P0, P1, _ = cm.world_shapes(robot.config(j, robot.base_on_feet(j)))
    return P0, P1, np.asarray(cm.base_radii, float)


def place_hidden(entry_of, body, distance_m: float, t_max: float = 1.5) -> dict[str, Any]:
    """``entry_of(t)`` (the primitive pushed ``t`` m out) at the ``t`` whose exact clearance to the
    ``body`` capsules is ``distance_m`` (bisection; the clearance grows with ``t``)."""
    from humanoid_reach_ros.sim.scene import scene_from_dict
    from humanoid_reach_ros.testing.truth import shapes_vs_primitives

    def clearance(t: float) -> float:
        prim = scene_from_dict({"primitives": [entry_of(t)]}).primitives[0]
        return float(shapes_vs_primitives([prim], *body, near_m=5.0)[0].min())
    lo, hi = 0.0, t_max
    if clearance(hi) < distance_m:
        raise ValueError(f"a hidden primitive stays within {distance_m} m of the body {t_max} m out")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if clearance(mid) < distance_m else (lo, mid)
    return entry_of(hi)


def make_scene(base_doc: dict[str, Any], seed: int, robot, cm, name: str) -> tuple[dict[str, Any], list[dict]]:
    """The base scene plus the hidden primitives of ``LAYOUT`` (module doc); returns the scene
    document and, per hidden primitive, its region, kind, side and clearance."""
    rng = np.random.default_rng(10_000 + seed)
    body = body_capsules(robot, cm)
    n = len(LAYOUT)
    lo, hi = DISTANCE_RANGE_M
    distances = lo + (hi - lo) * (np.arange(n) + rng.uniform(0, 1, n)) / n
    rng.shuffle(distances)
    hidden, info = [], []
    for k, ((region, side), d) in enumerate(zip(LAYOUT, distances)):
        spec = REGIONS[region]
        s = side or (1 if rng.random() < 0.5 else -1)
        a_lo, a_hi = (np.asarray(v, float) for v in spec["anchor"])
        anchor = rng.uniform(a_lo, a_hi)
        yaw = math.radians(rng.uniform(*spec["yaw_deg"]))
        if region in ("beside_hip", "under_arm"):
            anchor[1] *= s
            yaw *= s
        u = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        kind = str(rng.choice(spec["kinds"]))
        sub = np.random.default_rng(rng.integers(1 << 31))
        pname = f"hidden_{k}_{region}_{kind}"

        def entry_of(t: float, anchor=anchor, u=u, kind=kind, pname=pname, state=sub.bit_generator.state):
            g = np.random.default_rng()
            g.bit_generator.state = state            # the same sizes at every t
            return _primitive(kind, pname, anchor + t * u, u, g)
        hidden.append(place_hidden(entry_of, body, float(d)))
        info.append({"name": pname, "region": region, "kind": kind, "side": "left" if s > 0 else "right",
                     "clearance_m": round(float(d), 4)})
    doc = {k: v for k, v in base_doc.items() if k != "primitives"}
    doc["name"] = name
    doc["primitives"] = list(base_doc["primitives"]) + hidden
    doc["voxel_map"] = {"resolution_m": base_doc.get("voxel_map", {}).get("resolution_m", 0.02),
                        "extent": {"min": list(TRUTH_EXTENT[0]), "max": list(TRUTH_EXTENT[1])}}
    return doc, info


def sample_targets(scene, robot, cm, n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` targets all around the robot (module doc), each with its sector."""
    from humanoid_reach_ros.robot.shapes import point_segment_distance

    rng = np.random.default_rng(20_000 + seed)
    P0, P1, R = body_capsules(robot, cm)
    out: list[dict[str, Any]] = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 200 * n:
            raise RuntimeError(f"only {len(out)} of {n} targets found in free space")
        phi = rng.uniform(-math.pi, math.pi)
        rho = rng.uniform(*TARGET_RADIUS_M)
        p = np.array([rho * math.cos(phi), rho * math.sin(phi), rng.uniform(*TARGET_HEIGHT_M)])
        if float(scene.sdf(p[None], include_floor=False)[0]) < TARGET_CLEARANCE_M:
            continue
        if float((point_segment_distance(p, P0, P1)[0] - R).min()) < TARGET_BODY_CLEARANCE_M:
            continue
        deg = math.degrees(phi)
        sector = "front" if abs(deg) < 45 else "behind" if abs(deg) > 135 else "left" if deg > 0 else "right"
        out.append({"target": [round(float(v), 3) for v in p], "sector": sector})
    return out


# ---------------------------------------------------------------- the graph's flow
class RecordingClient:
    """``OperatorSession``'s client: ``reach_operator``'s ``Operator``, keeping every /plan_reach
    response and every /look outcome of the current target."""

    def __init__(self, operator) -> None:
        self.operator = operator
        self.responses: list[Any] = []
        self.looks: list[tuple[str, Any]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.operator, name)

    def plan(self, req: Any) -> Any:
        resp = self.operator.plan(req)
        self.responses.append(resp)
        return resp

    def look(self, *a: Any, **k: Any) -> tuple[str, Any]:
        outcome = self.operator.look(*a, **k)
        self.looks.append(outcome)
        return outcome


def response_record(resp: Any) -> dict[str, Any]:
    tr = resp.trajectory
    return {"code": int(resp.error_code.val), "success": bool(resp.success), "message": resp.message[:400],
            "arm": int(resp.arm), "retreat": resp.retreat,
            "unobserved_points": [[p.x, p.y, p.z] for p in resp.unobserved_points],
            "joint_names": list(tr.joint_names),
            "times": [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in tr.points],
            "positions": [list(p.positions) for p in tr.points]}


def run_target(sess, client, robot, tgt: dict[str, Any], seed: int, budget_s: float, log_err) -> dict[str, Any]:
    """One target through ``OperatorSession`` (plan with automatic looks, no execution)."""
    from humanoid_reach_ros.nodes.reach_operator import plan_request
    from humanoid_reach_ros.operator.cli import parse_args
    from humanoid_reach_ros.operator.session import OperatorSession

    rec: dict[str, Any] = {**tgt, "plan_seed": seed}
    sess.op.spin_for(0.1)                   # the probe's latest /joint_states: the start of this target
    rec["start_joints"] = sess.joints_now().tolist()
    args = parse_args(["--target", *(f"{v:g}" for v in tgt["target"]), "--seed", str(seed),
                       "--budget", f"{budget_s:g}", "--max-looks", str(MAX_LOOKS)])
    client.responses, client.looks = [], []
    text, err = io.StringIO(), io.StringIO()
    t0 = time.monotonic()
    code = OperatorSession(client, args, text, err).run(plan_request(args), io.StringIO())
    rec["wall_s"] = round(time.monotonic() - t0, 3)
    rec["exit_code"] = int(code)
    rec["responses"] = [response_record(r) for r in client.responses if r is not None]
    rec["codes"] = [r["code"] for r in rec["responses"]]
    rec["final_code"] = rec["codes"][-1] if rec["codes"] and client.responses[-1] is not None else None
    rec["looks"] = len(client.looks)
    rec["looks_ok"] = all(o == "done" and r is not None and r.success for o, r in client.looks)
    if err.getvalue():
        rec["stderr_tail"] = err.getvalue().strip().splitlines()[-4:]
        log_err(err.getvalue())
    return rec


def map_points(msg) -> np.ndarray:
    from humanoid_reach_ros.io import msgs
    return np.zeros((0, 3)) if msg is None else msgs.points_from_cloud(msg).points


def hidden_seen(scene, points: np.ndarray) -> dict[str, int]:
    """Per hidden primitive: the map voxels within ``SEEN_BY_MAP_M`` of its surface."""
    out = {}
    for p in scene.primitives:
        if p.group == HIDDEN_GROUP:
            out[p.name] = int(np.sum(np.abs(p.sdf(points)) <= SEEN_BY_MAP_M)) if len(points) else 0
    return out


def run_scene(out: Path, scene_path: Path, scene, targets: list[dict], seed: int, robot_name: str,
              budget_s: float, log) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """A fresh graph on the scene: one scan, then every target (module doc). Every target gets
    a record; one the graph could not run gets ``error`` (counted as missed)."""
    import session as bench_session
    from humanoid_reach_ros.io.endpoints import LATCHED
    from humanoid_reach_ros.nodes.reach_operator import Operator
    from humanoid_reach_ros.operator.cli import parse_args
    from humanoid_reach_ros.operator.session import OperatorSession
    from sensor_msgs.msg import PointCloud2

    out.mkdir(parents=True, exist_ok=True)
    records: list[dict[str, Any]] = []
    info: dict[str, Any] = {}
    t0 = time.monotonic()
    sess = op = None
    errlog = open(out / "operator.err", "w", encoding="utf-8")

    def log_err(text: str) -> None:
        errlog.write(text)
        errlog.flush()
    try:
        sess = bench_session.Session(out, scene_path, robot_name, log)
        sess.op.recording = False
        info["graph_up_s"] = round(time.monotonic() - t0, 1)
        latest: dict[str, Any] = {"map": None}
        sess.op.node.create_subscription(PointCloud2, "/voxel_map", lambda m: latest.__setitem__("map", m), LATCHED)
        for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
            if key in sess.bench.graph.env:      # the operator joins the graph's isolated domain
                os.environ[key] = sess.bench.graph.env[key]
        op = Operator(60.0, errlog)
        client = RecordingClient(op)
        args = parse_args(["--scan"])
        t_scan = time.monotonic()
        code = OperatorSession(client, args, io.StringIO(), errlog).run(None, io.StringIO())
        if code != 0:
            raise RuntimeError(f"reach_operator --scan ended with exit code {code}")
        # the mapper has integrated the scan: no new /voxel_map for a second
        sess.op.spin_until(lambda: sess.op.maps and sess.op.maps[-1][0] > t_scan
                           and time.monotonic() - sess.op.maps[-1][0] > 1.0, 30.0, "the /voxel_map of the scan")
        info["scan_s"] = round(time.monotonic() - t_scan, 1)
        info["map_voxels_after_scan"] = int(sess.op.maps[-1][1])
        info["hidden_seen_by_scan"] = hidden_seen(scene, map_points(latest["map"]))
        log(f"  scan: {info['map_voxels_after_scan']} voxels; hidden voxels seen {info['hidden_seen_by_scan']}")
        for k, tgt in enumerate(targets):
            try:
                sess.bench.graph.check_alive()
                rec = run_target(sess, client, sess.robot, tgt, seed * 1000 + k, budget_s, log_err)
            except (RuntimeError, AssertionError, TimeoutError, ValueError) as exc:
                rec = {**tgt, "plan_seed": seed * 1000 + k, "error": str(exc)[-2000:]}
            rec["index"] = k
            records.append(rec)
            fc = rec.get("final_code")
            log(f"  {k:3d} {tgt['sector']:6s} {tgt['target']} -> "
                f"{code_name(fc) if fc is not None else 'NO ANSWER'} codes {rec.get('codes')} looks "
                f"{rec.get('looks')} {rec.get('wall_s', '-')} s" + (f" ERROR {rec['error'][-200:]}" if 'error' in rec
                                                                   else ""))
        sess.op.spin_for(1.0)
        info["hidden_seen_at_end"] = hidden_seen(scene, map_points(latest["map"]))
    except (RuntimeError, AssertionError, TimeoutError) as exc:     # the graph did not come up or died
        log(f"  scene failed: {exc}")
        info["error"] = str(exc)[-3000:]
    finally:
        if op is not None:
            op.close()
        if sess is not None:
            info["exit_codes"] = sess.close()
        errlog.close()
    done = {r["index"] for r in records}
    for k, tgt in enumerate(targets):      # every target counts: those never run are missed
        if k not in done:
            records.append({**tgt, "plan_seed": seed * 1000 + k, "index": k,
                            "error": "not run: " + info.get("error", "the scene's graph stopped")[-300:]})
    info["wall_s"] = round(time.monotonic() - t0, 1)
    return sorted(records, key=lambda r: r["index"]), info


# ---------------------------------------------------------------- the truth
class Truth:
    """The truth of one scene: the audit of returned plans, and the oracle of feasible and
    observable targets (module doc)."""

    def __init__(self, robot, cm, scene, budget_s: float, start: np.ndarray, log,
                 body_margin_m: float = BODY_MARGIN_M, stance_m: float = 0.0,
                 hidden: list[dict[str, Any]] | None = None) -> None:
        import dataclasses

        import generality
        from humanoid_reach_ros.control.gaze import GazeSolver
        from humanoid_reach_ros.planning.reach import ReachPlanner
        from humanoid_reach_ros.scene.planning_scene import PlanningScene, SceneParams
        from humanoid_reach_ros.testing.truth import TrajectoryAudit

        self.robot, self.cm, self.scene, self.budget_s = robot, cm, scene, budget_s
        self.body_margin_m = float(body_margin_m)
        self.stance_m = float(stance_m)
        # a hidden primitive's clearance to the body at half-sitting (make_scene's drawn distance)
        self.hidden_clearance = {h["name"]: float(h["clearance_m"]) for h in (hidden or [])}
        self.audit = TrajectoryAudit(robot, cm, scene.primitives)
        self.gaze = GazeSolver(robot)
        params = generality.planner_params()
        t0 = time.monotonic()
        shell, self.unobservable_cells = self.unobservable_shell(np.asarray(start, float), params.resolution_m)
        log(f"  truth: {self.unobservable_cells} cells of {CELL_M:g} m no reachable gaze sees, a shell of "
            f"{len(shell)} voxels ({time.monotonic() - t0:.1f} s)")
        fields = {f.name for f in dataclasses.fields(SceneParams)}
        policy = {"resolution_m": params.resolution_m, "safety_margin_m": params.safety_margin_m,
                  "unobserved_space": "occupied"}
        if "body_clearance_m" in fields:     # the robot's own volume (grown by the margin) is known free
            policy["body_clearance_m"] = self.body_margin_m
        self.planner = ReachPlanner(robot, params=params, scene=PlanningScene(robot, SceneParams(**policy), cm))
        self.planner.set_map(scene.voxelize(params.resolution_m, TRUTH_EXTENT))
        self.planner.scene.set_unobserved(shell, np.zeros((0, 3)))
        self.planner.warm_up()

    def check_plan(self, resp: dict[str, Any]) -> dict[str, Any]:
        from humanoid_reach_ros.testing.truth import model_positions
        pos = model_positions(self.robot, resp["joint_names"], resp["positions"])
        c, n = self.audit.check(np.asarray(resp["times"], float), pos)
        hidden = c.primitive and self.scene.primitive(c.primitive).group == HIDDEN_GROUP
        # an obstacle the scene put inside the stance zone breaks the policy's declared assumption
        in_stance = bool(hidden) and self.hidden_clearance.get(c.primitive, math.inf) < self.stance_m
        return {"penetrating": c.penetrating, "distance_mm": round(c.distance_m * 1e3, 2),
                "primitive": c.primitive, "hidden": bool(hidden), "in_stance_zone": in_stance, "shape": c.shape,
                "time_s": round(c.time_s, 3), "configurations": n}

    def _gaze_grid(self, joints: np.ndarray) -> np.ndarray:
        """Joint vectors with the gaze joints over a grid of their limits (chest 9 x 7, neck 10 x 10)."""
        g = self.gaze
        axes = [np.linspace(lo, hi, k) for lo, hi, k in zip(g.lower, g.upper, (9, 7, 10, 10))]
        grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(axes), -1).T
        J = np.tile(joints, (len(grid), 1))
        J[:, g.index] = grid
        return J

    def unobservable_shell(self, start: np.ndarray, resolution_m: float) -> tuple[np.ndarray, int]:
        """The voxels (resolution ``resolution_m``) of the outer layer of the space no gaze
        reachable from ``start`` sees (``CELL_M`` cells of ``OBSERVE_BOX`` whose centre no gaze of
        the grid sees, outside the start's body grown by ``BODY_MARGIN_M`` and outside the stance
        zone, the body at half-sitting grown by ``stance_m``): an obstacle a plan
        cannot cross, so that it never enters that space; and how many cells that space has."""
        from humanoid_reach_ros.robot.shapes import point_segment_distance
        lo, hi = (np.asarray(v, float) for v in OBSERVE_BOX)
        axes = [np.arange(a, b, CELL_M) + 0.5 * CELL_M for a, b in zip(lo, hi)]
        dims = tuple(len(a) for a in axes)
        C = np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T
        seen = np.zeros(len(C), bool)
        for j in self._gaze_grid(start):
            todo = np.flatnonzero(~seen)
            if not len(todo):
                break
            seen[todo] = self.gaze.sees(j, C[todo])
        B0, B1, BR = body_capsules(self.robot, self.cm, start)
        body = np.zeros(len(C), bool)
        for a, b, r in zip(B0, B1, BR):
            body |= point_segment_distance(C, a, b)[0] <= r + self.body_margin_m
        if self.stance_m > 0.0:      # the stance zone: the body at half-sitting grown by stance_m, known free
            for a, b, r in zip(*body_capsules(self.robot, self.cm)):
                body |= point_segment_distance(C, a, b)[0] <= r + self.stance_m
        unobs = (~seen & ~body).reshape(dims)
        inner = unobs.copy()
        for ax in range(3):          # a cell with a seen (or body) neighbour is on the shell
            for step in (1, -1):
                nb = np.roll(unobs, step, axis=ax)
                edge = [slice(None)] * 3
                edge[ax] = 0 if step == 1 else -1
                nb[tuple(edge)] = True     # beyond the box: as unobservable (no wall there)
                inner &= nb
        shell = C[(unobs & ~inner).reshape(-1)]
        k = int(round(CELL_M / resolution_m))
        sub = (np.array(np.meshgrid(*[np.arange(k)] * 3, indexing="ij")).reshape(3, -1).T + 0.5) * resolution_m
        V = (shell[:, None, :] - 0.5 * CELL_M + sub[None]).reshape(-1, 3)
        return V, int(unobs.sum())

    def feasibility(self, rec: dict[str, Any]) -> dict[str, Any]:
        """The oracle's plan of the target: SUCCESS means feasible and observable."""
        from humanoid_reach_ros.planning.reach import PlanRequest
        from humanoid_reach_ros.planning.wgr import valve_region

        start = np.asarray(rec["start_joints"], float)
        t0 = time.monotonic()
        o = self.planner.plan(start, PlanRequest(valve_region(np.asarray(rec["target"], float)), arm="auto",
                                                 seed=int(rec["plan_seed"]), time_budget_s=self.budget_s))
        return {"feasible_observable": bool(o.success), "code": o.error.name,
                "plan_s": round(time.monotonic() - t0, 3)}


def truth_for(records: list[dict[str, Any]], truth: Truth, log) -> None:
    """Adds ``check`` (per SUCCESS plan) and ``truth`` to each record; an error is kept in the
    record (``check_error`` / ``truth_error``: a missing measurement, counted against the graph)."""
    for rec in records:
        final = (rec.get("responses") or [None])[-1]
        if final is not None and final["success"]:
            try:
                rec["check"] = truth.check_plan(final)
            except (ValueError, KeyError, IndexError) as exc:
                rec["check_error"] = str(exc)
        if "start_joints" in rec:
            try:     # where the looks before it left the robot (they execute: a balanced gaze moves the legs)
                c = truth.audit.clearance(np.asarray(rec["start_joints"], float))
                rec["start_check"] = {"penetrating": c.penetrating, "distance_mm": round(c.distance_m * 1e3, 2),
                                      "primitive": c.primitive, "shape": c.shape}
                rec["truth"] = truth.feasibility(rec)
            except (ValueError, KeyError, RuntimeError) as exc:
                rec["truth_error"] = str(exc)
        else:
            rec["truth_error"] = "no start posture: the target never ran"
        c, t = rec.get("check"), rec.get("truth", {})
        log(f"  {rec['index']:3d} {rec['sector']:6s} {rec['target']} graph "
            f"{code_name(rec['final_code']) if rec.get('final_code') is not None else 'NO ANSWER'}, oracle "
            f"{t.get('code', rec.get('truth_error', '?'))}"
            + (f"; plan {'PENETRATES' if c['penetrating'] else 'clear'} {c['distance_mm']} mm {c['primitive']} "
               f"{c['shape']} at {c['time_s']} s" if c else ""))


# ---------------------------------------------------------------- the figures
def summarize(records: list[dict[str, Any]], max_looks: int = MAX_LOOKS) -> dict[str, Any]:
    """The bench's figures from per-target records (module doc; every target in every denominator)."""
    codes: Counter[str] = Counter()
    penetrating, unchecked, checked = [], [], 0
    fo = fo_reached = truth_missing = feasible_unobservable = 0
    unobservable = unobserved = 0
    looks = looks_failed = 0
    starts_inside: list[dict[str, Any]] = []
    for r in records:
        fc = r.get("final_code") if "error" not in r else None
        codes[code_name(fc) if fc is not None else "NO_ANSWER"] += 1
        unobservable += fc == ErrorCode.UNOBSERVABLE_SPACE
        unobserved += fc == ErrorCode.UNOBSERVED_SPACE
        looks += int(r.get("looks") or 0)
        if (r.get("start_check") or {}).get("penetrating"):
            starts_inside.append(r)
        looks_failed += 0 if r.get("looks_ok", True) else 1
        success = fc == ErrorCode.SUCCESS
        clean = False
        if success:
            c = r.get("check")
            if c is None:
                unchecked.append(r)
            else:
                checked += 1
                if c["penetrating"]:
                    penetrating.append(r)
                else:
                    clean = True
        t = r.get("truth")
        if t is None:
            truth_missing += 1
            is_fo = True                      # unknown truth: counted feasible and observable
        else:
            is_fo = bool(t["feasible_observable"])
            feasible_unobservable += t["code"] in (ErrorCode.UNOBSERVED_SPACE.name, ErrorCode.UNOBSERVABLE_SPACE.name)
        if is_fo:
            fo += 1
            fo_reached += clean and int(r.get("looks") or 0) <= max_looks

    def case(r: dict[str, Any]) -> dict[str, Any]:
        c = r.get("check") or {}
        return {"scene": r.get("scene"), "seed": r.get("seed"), "index": r.get("index"), "target": r.get("target"),
                "sector": r.get("sector"), "plan_seed": r.get("plan_seed"),
                "depth_mm": -c["distance_mm"] if c else None, "primitive": c.get("primitive"),
                "hidden": c.get("hidden"), "in_stance_zone": c.get("in_stance_zone"), "shape": c.get("shape"),
                "time_s": c.get("time_s"),
                "looks": r.get("looks"), "unchecked": not c}
    cases = sorted((case(r) for r in penetrating + unchecked), key=lambda c: -(c["depth_mm"] or math.inf))
    worst = next((c for c in cases if c["depth_mm"] is not None), None)
    return {
        "unseen_plans": checked + len(unchecked),
        "plans_penetrating_true_obstacles": len(penetrating) + len(unchecked),
        "plans_unchecked": len(unchecked),
        "worst_penetration_mm": worst["depth_mm"] if worst else 0.0,
        "worst_penetration": worst,
        "penetrating_through_hidden": sum(1 for c in cases if c["hidden"]),
        # through an obstacle the scene put within stance_clearance_m of the body: the policy's declared
        # assumption (that space is kept clear) broken by the scene, counted apart (still in the total above)
        "penetrating_in_stance_zone": sum(1 for c in cases if c.get("in_stance_zone")),
        "plans_penetrating_beyond_stance_zone": sum(1 for c in cases if not c.get("in_stance_zone")),
        "unobservable_answers": int(unobservable),
        "unobserved_answers": int(unobserved),
        "feasible_observable_targets": fo,
        "feasible_observable_reached": int(fo_reached),
        "feasible_observable_success_rate": round(fo_reached / fo, 4) if fo else 0.0,
        "truth_feasible_only_through_unobservable": feasible_unobservable, "truth_missing": truth_missing,
        "codes": dict(sorted(codes.items())),
        "targets": len(records),
        "targets_by_sector": dict(sorted(Counter(str(r.get("sector")) for r in records).items())),
        "auto_looks": looks, "targets_with_a_failed_look": looks_failed,
        # the robot's measured posture at a target's start inside a true obstacle: an executed look went there
        "starts_inside_true_obstacles": len(starts_inside),
        "starts_inside": [{"scene": r.get("scene"), "index": r.get("index"),
                           "depth_mm": -r["start_check"]["distance_mm"], "primitive": r["start_check"]["primitive"],
                           "shape": r["start_check"]["shape"]} for r in starts_inside],
        "penetrating_cases": cases,
    }


def judge(figures: dict[str, Any]) -> dict[str, dict[str, Any]]:
    import graph as bench_graph
    return bench_graph.judge(figures, TARGETS)


def commit() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                               capture_output=True, text=True, timeout=10)
        return head.stdout.strip() + (" (uncommitted changes in the tree)" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError) as exc:
        return f"unknown ({exc})"


def main(argv: list[str] | None = None) -> int:
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import load_collision_model
    from humanoid_reach_ros.robot.spec import DEFAULT_ROBOT, robots
    from humanoid_reach_ros.sim.scene import load_scene, scene_from_dict
    from humanoid_reach_ros.testing.machine import describe as machine

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=robots(), default=DEFAULT_ROBOT, help="robot (default %(default)s)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4], help="one generated scene per seed")
    ap.add_argument("--targets-per-scene", type=int, default=50, help="random targets per scene (default 50)")
    ap.add_argument("--budget", type=float, default=BUDGET_S, help="planning budget [s] of the graph's and the "
                    "truth's plans (default %(default)s)")
    ap.add_argument("--quick", action="store_true", help=f"one scene (the first seed), {QUICK_TARGETS} targets")
    ap.add_argument("--out", default="out/unseen", help="scenes, logs, records and a copy of the JSON")
    ap.add_argument("--body-margin", type=float, default=BODY_MARGIN_M, help="the oracle's known-free space: "
                    "the robot's own volume grown by this [m] (default %(default)s: issue 31's self-filter margin)")
    ap.add_argument("--stance", type=float, default=None, help="the oracle's stance zone [m] (default: the voxel "
                    "mapper's stance_clearance_m, the policy's assumption; 0: none)")
    ap.add_argument("--truth-only", action="store_true", help="no graph: the truth of the scenes and records an "
                    "earlier run left in --out, computed again (same --seeds, --quick and --robot)")
    args = ap.parse_args(argv)
    if args.targets_per_scene < 1 or not (0 < args.budget <= 60) or not (0 <= args.body_margin <= 0.5):
        ap.error("--targets-per-scene must be >= 1, --budget in (0, 60] and --body-margin in [0, 0.5]")
    stance = stance_clearance_m() if args.stance is None else args.stance
    if not (0.0 <= stance <= 0.5):
        ap.error(f"--stance must be in [0, 0.5], got {stance}")
    seeds = args.seeds[:1] if args.quick else args.seeds
    per_scene = min(args.targets_per_scene, QUICK_TARGETS) if args.quick else args.targets_per_scene
    out = Path(args.out).resolve()
    (out / "scenes").mkdir(parents=True, exist_ok=True)

    def log(text: str) -> None:
        print(f"[bench/unseen] {text}", flush=True)

    import session as bench_session
    bench_session.stop_on_signals()
    t0 = time.monotonic()
    head = commit()
    robot = RobotModel(args.robot)
    cm = load_collision_model(None, robot)
    base_doc = yaml.safe_load(Path(robot.spec.demo_scene).read_text())
    records: list[dict[str, Any]] = []
    scenes: dict[str, Any] = {}
    for seed in seeds:
        name = f"unseen_{args.robot}_s{seed}"
        path = out / "scenes" / f"{name}.yaml"
        if args.truth_only:      # the recorded graph runs of an earlier run, their truth computed again
            scene = load_scene(path)
            recs = [json.loads(line) for line in (out / name / "records.jsonl").read_text().splitlines()]
            for r in recs:
                for key in ("check", "truth", "check_error", "truth_error"):
                    r.pop(key, None)
            prev = json.loads((out / "unseen.json").read_text()).get("scenes", {}) if (out / "unseen.json").exists() \
                else {}
            info = prev.get(name, {})
        else:
            doc, hidden = make_scene(base_doc, seed, robot, cm, name)
            path.write_text(yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))
            scene = scene_from_dict(doc, source=str(path))
            targets = sample_targets(scene, robot, cm, per_scene, seed)
            log(f"scene {name}: hidden {[(h['region'], h['kind'], h['clearance_m']) for h in hidden]}; "
                f"{len(targets)} targets; graph up ...")
            recs, info = run_scene(out / name, path, scene, targets, seed, args.robot, args.budget, log)
            info = {"hidden": hidden, **{k: v for k, v in info.items() if k != "error"},
                    **({"error": info["error"][-500:]} if "error" in info else {})}
            for r in recs:
                r["scene"], r["seed"] = name, seed
            log(f"  graph done in {info['wall_s']} s; the truth ...")
        starts = [r["start_joints"] for r in recs if "start_joints" in r]
        if starts:
            truth_for(recs, Truth(robot, cm, scene, args.budget, np.asarray(starts[0], float), log,
                                  args.body_margin, stance, info.get("hidden")), log)
        else:
            for r in recs:
                r["truth_error"] = "no target ran"
        with open(out / name / "records.jsonl", "w", encoding="utf-8") as f:
            for r in recs:
                f.write(json.dumps(r) + "\n")
        records += recs
        scenes[name] = info
    figures = summarize(records)
    figures["targets_judged"] = judge(figures)
    figures["targets_met"] = all(t["met"] for t in figures["targets_judged"].values())
    if args.truth_only and (out / "unseen.json").exists():   # the graph ran on the earlier run's commit
        head = {"commit": json.loads((out / "unseen.json").read_text()).get("commit"), "truth_commit": head}
    else:
        head = {"commit": head}
    figures.update(**head)
    figures.update(seeds=seeds, targets_per_scene=per_scene, budget_s=args.budget, robot=args.robot,
                   truth_recomputed=bool(args.truth_only), body_margin_m=args.body_margin, stance_m=stance,
                   scenes=scenes, machine=machine(), bench="unseen",
                   wall_s=round(time.monotonic() - t0, 1))
    (out / "unseen.json").write_text(json.dumps(figures, indent=2))
    for key, t in figures["targets_judged"].items():
        log(f"{'ok  ' if t['met'] else 'MISS'} {key}: {t['value']} (target {t['target']})")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
