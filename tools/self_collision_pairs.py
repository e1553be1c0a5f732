#!/usr/bin/env python3
"""Review a robot's self-collision pairs (collision.yaml) against sampled postures.

    python tools/self_collision_pairs.py --robot talos [--samples 3000] [--near 0.05] [--seed 0]

Postures are drawn uniformly within the joint limits (waist fixed, as the pair rule of
config/robots/*/collision.yaml says). Reported:

* listed pairs in collision at half-sitting (there must be none) and at q = 0;
* listed pairs that never came within ``--near`` m (the rule would leave them out, unless
  their mirror image came that close: the lists are kept left-right symmetric);
* pairs NOT listed, of shapes on different links, that came within ``--near`` m and are in
  collision in less than 95 % of the postures (always-overlapping pairs are neighbours):
  candidates the rule asks to add or to name as neighbours.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model, segment_segment_distance  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", required=True)
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--near", type=float, default=0.05, help="distance that makes a pair matter [m]")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    robot = RobotModel(a.robot)
    cm = load_collision_model(None, robot)
    names, S = cm.names, cm.n_shapes
    iu = np.array([(i, j) for i in range(S) for j in range(i + 1, S)
                   if cm.shapes[i].link != cm.shapes[j].link], dtype=np.intp)
    listed = {frozenset(p) for p in cm.pairs}

    def dists(q):
        P0, P1, r = cm.world_shapes(robot.forward(q))
        d, _, _ = segment_segment_distance(P0[iu[:, 0]], P1[iu[:, 0]], P0[iu[:, 1]], P1[iu[:, 1]])
        return d - r[iu[:, 0]] - r[iu[:, 1]]

    rng = np.random.default_rng(a.seed)
    D = np.array([dists(robot.config(rng.uniform(robot.lower, robot.upper))) for _ in range(a.samples)])
    d_min, hit = D.min(axis=0), (D < 0).mean(axis=0)
    d_hs, d_zero = dists(robot.half_sitting()), dists(robot.config(np.zeros(robot.n_joints)))
    key = [frozenset((names[i], names[j])) for i, j in iu]
    is_listed = np.array([k in listed for k in key])
    print(f"{robot.name}: {S} shapes, {len(listed)} pairs listed, {len(iu)} cross-link pairs, {a.samples} postures")
    for title, sel in (("listed, in collision at half-sitting", is_listed & (d_hs < 0)),
                       ("listed, in collision at q = 0", is_listed & (d_zero < 0)),
                       (f"listed, never within {a.near} m", is_listed & (d_min > a.near)),
                       (f"not listed, within {a.near} m, colliding in < 95 % of postures",
                        ~is_listed & (d_min <= a.near) & (hit < 0.95))):
        rows = np.flatnonzero(sel)
        print(f"\n{title}: {len(rows)}")
        for k in rows[np.argsort(d_min[rows])]:
            a_, b_ = names[iu[k, 0]], names[iu[k, 1]]
            print(f"  {a_:>18s} - {b_:<18s} min {d_min[k]:+.3f} m, colliding in {100 * hit[k]:5.1f} %, "
                  f"half-sitting {d_hs[k]:+.3f} m")


if __name__ == "__main__":
    main()
