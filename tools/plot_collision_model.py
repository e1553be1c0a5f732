#!/usr/bin/env python3
"""Draw the sphere / capsule collision model of the half-sitting robot (cf. Kanehiro et
al., Fig. 2 right): front and side views, with the URDF link boxes it approximates (a URDF
of meshes has none: the skeleton of joint origins is drawn).

    python tools/plot_collision_model.py [--robot hrp2] [--out doc/collision_model.png] [--padding 0.0]

Orthographic views: a capsule projects to a "stadium" (the projected segment swept by
a disc of the capsule's radius), a sphere to a disc; both are drawn exactly.
"""
from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402
from humanoid_reach_ros.robot.shapes import load_collision_model  # noqa: E402

COLOURS = {"r_": "tab:red", "l_": "tab:blue"}
TORSO = "tab:green"


def colour(name: str) -> str:
    return COLOURS.get(name[:2], TORSO)


def stadium(a: np.ndarray, b: np.ndarray, r: float, n: int = 24) -> np.ndarray:
    """Outline of the 2-D segment a-b swept by a disc of radius r."""
    d = b - a
    length = float(np.hypot(*d))
    theta = float(np.arctan2(d[1], d[0])) if length > 1e-12 else 0.0
    arc_b = theta + np.linspace(-np.pi / 2, np.pi / 2, n)
    arc_a = theta + np.linspace(np.pi / 2, 3 * np.pi / 2, n)
    pts_b = b + r * np.column_stack([np.cos(arc_b), np.sin(arc_b)])
    pts_a = a + r * np.column_stack([np.cos(arc_a), np.sin(arc_a)])
    return np.vstack([pts_b, pts_a])


def hull(points: np.ndarray) -> np.ndarray:
    """2-D convex hull (Andrew's monotone chain), counter-clockwise."""
    pts = sorted(map(tuple, np.round(points, 12)))

    def half(seq):
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2 and _turn(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(half(pts) + half(reversed(pts)))


def _turn(o, a, b) -> float:
    """z of (a - o) x (b - o): > 0 for a counter-clockwise turn."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def urdf_boxes(robot: RobotModel, data) -> list[np.ndarray]:
    """World corners (8, 3) of every URDF visual box."""
    out = []
    for link in ET.fromstring(robot.urdf_xml).findall("link"):
        box = link.find("visual/geometry/box")
        if box is None:
            continue
        centre = np.array(link.find("visual/origin").get("xyz").split(), dtype=float)
        size = np.array(box.get("size").split(), dtype=float)
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        M = data.oMf[robot.frame_id(link.get("name"))]
        out.append((centre + 0.5 * signs * size) @ M.rotation.T + M.translation)
    return out


def draw_view(ax, axes: tuple[int, int], depth_axis: int, depth_sign: float, cm, P0, P1, radii, boxes,
              skeleton, ees, title: str) -> None:
    u, v = axes
    for corners in boxes:
        ax.add_patch(Polygon(hull(corners[:, [u, v]]), closed=True, fill=False, ec="0.55", lw=0.6, ls="--"))
    # far shapes first so that near ones are drawn on top
    depth = depth_sign * 0.5 * (P0[:, depth_axis] + P1[:, depth_axis])
    for k in np.argsort(depth):
        name = cm.shapes[k].name
        a, b, r = P0[k, [u, v]], P1[k, [u, v]], radii[k]
        c = colour(name)
        if cm.shapes[k].is_sphere:
            ax.add_patch(Circle(a, r, fc=c, ec="k", alpha=0.35, lw=0.8))
        else:
            ax.add_patch(Polygon(stadium(a, b, r), closed=True, fc=c, ec="k", alpha=0.35, lw=0.8))
            ax.plot(*np.column_stack([a, b]), color="k", lw=0.5, alpha=0.6)
    for chain in skeleton:
        ax.plot(chain[:, u], chain[:, v], "-o", color="k", lw=1.0, ms=2.0)
    for p in ees:
        ax.plot(p[u], p[v], marker="x", color="m", ms=7, mew=1.5)
    ax.axhline(0.0, color="saddlebrown", lw=1.5)
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.grid(True, lw=0.3, alpha=0.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="hrp2", help="robot of config/robots (or a robot.yaml path)")
    ap.add_argument("--out", default=None,
                    help="default: doc/collision_model.png (hrp2), doc/collision_model_<robot>.png")
    ap.add_argument("--padding", type=float, default=None, help="override padding_m")
    args = ap.parse_args()

    robot = RobotModel(args.robot)
    cm = load_collision_model(None, robot, padding_m=args.padding)
    q = robot.half_sitting()
    data = robot.forward(q)
    P0, P1, radii = cm.world_shapes(data)
    boxes = urdf_boxes(robot, data)

    def pos(frame: str) -> np.ndarray:
        return data.oMf[robot.frame_id(frame)].translation.copy()

    def limb_chain(name: str) -> list[np.ndarray]:
        """Root link, every joint origin of the limb, tip."""
        limb = robot.limbs[name]
        m = robot.model
        return [pos(limb.root)] + [data.oMi[m.getJointId(j)].translation.copy() for j in limb.joints] + \
            [pos(limb.tip)]

    legs = limb_chain("right_leg")[::-1] + limb_chain("left_leg")
    arms = limb_chain("right_arm")[::-1] + limb_chain("left_arm")
    spine = [pos(robot.base_link), pos(robot.spec.chest_link), pos(robot.camera_frame)]
    skeleton = [np.array(legs), np.array(spine), np.array(arms)]
    ees = [pos(f) for f in robot.hand_frames.values()]
    height = float(max(P1[:, 2].max(), P0[:, 2].max()) + radii.max()) + 0.05

    fig, (front, side) = plt.subplots(1, 2, figsize=(11, 8.5), gridspec_kw={"width_ratios": [1.15, 1]})
    draw_view(front, (1, 2), 0, 1.0, cm, P0, P1, radii, boxes, skeleton, ees,
              "front (from +x; robot's left on the right)")
    draw_view(side, (0, 2), 1, -1.0, cm, P0, P1, radii, boxes, skeleton, ees, "side (from -y, the robot's right)")
    half = max(0.55, float(np.abs(np.concatenate([P0[:, 1], P1[:, 1]])).max() + radii.max() + 0.05))
    front.set_xlim(-half, half)
    side.set_xlim(-max(0.45, half - 0.1), max(0.45, half - 0.1))
    for ax in (front, side):
        ax.set_ylim(-0.05, max(1.65, height))
    front.set_xlabel("y [m]")
    side.set_xlabel("x [m]")
    front.set_ylabel("z [m]")
    fig.suptitle(
        f"{robot.name} collision model, half-sitting: {cm.n_shapes} shapes "
        f"({sum(s.is_sphere for s in cm.shapes)} spheres), {cm.n_pairs} self-collision pairs, "
        f"padding {cm.padding_m:g} m\n"
        "filled: shapes (red right, blue left, green torso); dashed: URDF link boxes; "
        "line: joint origins; x: hand frames"
    )
    fig.tight_layout()
    default = "collision_model.png" if args.robot == "hrp2" else f"collision_model_{robot.name}.png"
    out = Path(args.out) if args.out else ROOT / "doc" / default
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
