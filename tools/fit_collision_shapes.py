#!/usr/bin/env python3
"""Fit capsules to the mesh geometry of a robot's links: a starting point for a
``collision.yaml`` (docs/adding_a_robot.md), printed as YAML per link.

    python tools/fit_collision_shapes.py --robot talos [--link arm_left_3_link:2 ...] [--kind collision]

For every link that carries meshes (the URDF's collision geometry by default; a fixed
link's meshes count for the moving link it is welded to), the surface is sampled
(area-weighted, ``--density`` points per m^2, at least 200 per link) in the link's
frame, ``k`` capsules (``--link name:k``, default 1) are initialised on the k-means
clusters of the samples along their principal axis and refined together (Powell) to
the smallest total volume that leaves no sample more than ``--slack`` metres outside.
Reported per link: the shapes, the share of samples inside and the farthest sample
outside. The result is a draft: round it, merge shapes across links that share an
origin, shorten what must stay clear of a grasp point, and write why in the YAML.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import pinocchio as pin  # noqa: E402
from scipy.optimize import minimize  # noqa: E402

from humanoid_reach_ros.robot.model import RobotModel  # noqa: E402


def _triangles(geom) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices (V, 3), triangles (T, 3)) of a mesh, boxes and cylinders as meshes; None otherwise."""
    if hasattr(geom, "num_tris") and callable(getattr(geom, "vertices", None)):
        v = np.asarray(geom.vertices())   # coal has applied the URDF's mesh scale
        tri = geom.tri_indices
        return v, np.array([[tri(k)[0], tri(k)[1], tri(k)[2]] for k in range(geom.num_tris)], dtype=np.intp)
    if hasattr(geom, "halfSide"):
        h = np.asarray(geom.halfSide)
        v = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float) * h
        faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
                 (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
        return v, np.array(faces, dtype=np.intp)
    if hasattr(geom, "halfLength") and hasattr(geom, "radius"):
        n = 24
        ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        ring = np.column_stack([geom.radius * np.cos(ang), geom.radius * np.sin(ang)])
        v = np.vstack([np.column_stack([ring, np.full(n, -geom.halfLength)]),
                       np.column_stack([ring, np.full(n, geom.halfLength)]), [[0, 0, -geom.halfLength]],
                       [[0, 0, geom.halfLength]]])
        faces = [(k, (k + 1) % n, n + k) for k in range(n)] + [((k + 1) % n, n + (k + 1) % n, n + k) for k in range(n)]
        faces += [(2 * n, (k + 1) % n, k) for k in range(n)] + [(2 * n + 1, n + k, n + (k + 1) % n) for k in range(n)]
        return v, np.array(faces, dtype=np.intp)
    return None


def link_surfaces(robot: RobotModel, kind: str = "collision", density: float = 4.0e4,
                  seed: int = 0) -> dict[str, np.ndarray]:
    """Moving link name -> (N, 3) surface samples of its geometry (and of the fixed links
    welded to it) in its frame. Needs the meshes: the URDF's package must be installed
    (``RobotSpec.package_dirs``)."""
    m = robot.model
    gtype = {"collision": pin.GeometryType.COLLISION, "visual": pin.GeometryType.VISUAL}[kind]
    dirs = [str(d) for d in robot.spec.package_dirs] or [str(robot.urdf_path.parent)]
    geom = pin.buildGeomFromUrdfString(m, robot.urdf_xml, gtype, package_dirs=dirs)
    body = {}
    for f in m.frames:   # the link frame of each joint: a body frame at the joint's origin
        if f.type == pin.FrameType.BODY and f.parentJoint not in body and \
                np.allclose(f.placement.homogeneous, np.eye(4)):
            body[f.parentJoint] = f.name
    rng = np.random.default_rng(seed)
    out: dict[str, list[np.ndarray]] = {}
    for obj in geom.geometryObjects:
        mesh = _triangles(obj.geometry)
        if mesh is None:
            continue
        v, tri = mesh
        a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        n = max(int(area.sum() * density), 50)
        k = rng.choice(len(tri), size=n, p=area / area.sum())
        u, w = rng.random(n), rng.random(n)
        flip = u + w > 1.0
        u[flip], w[flip] = 1.0 - u[flip], 1.0 - w[flip]
        pts = a[k] + u[:, None] * (b[k] - a[k]) + w[:, None] * (c[k] - a[k])
        pts = np.vstack([pts, v])
        pts = pts @ obj.placement.rotation.T + obj.placement.translation    # in the joint's frame
        out.setdefault(body.get(obj.parentJoint, m.names[obj.parentJoint]), []).append(pts)
    return {name: np.vstack(p) for name, p in out.items()}


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    dd = float(d @ d)
    t = np.clip((p - a) @ d / dd, 0.0, 1.0) if dd > 1e-14 else np.zeros(len(p))
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def outside(p: np.ndarray, caps) -> np.ndarray:
    """Signed distance of each point to the union of capsules ``[(a, b, r), ...]`` (> 0 outside)."""
    return np.min([segment_distance(p, a, b) - r for a, b, r in caps], axis=0)


def _volume(caps) -> float:
    return float(sum(np.pi * r * r * np.linalg.norm(b - a) + 4.0 / 3.0 * np.pi * r ** 3 for a, b, r in caps))


def _initial(p: np.ndarray, k: int, rng) -> list:
    c = p.mean(axis=0)
    axis = np.linalg.eigh(np.cov((p - c).T))[1][:, -1]
    t = (p - c) @ axis
    edges = np.quantile(t, np.linspace(0, 1, k + 1))
    caps = []
    for j in range(k):
        q = p[(t >= edges[j]) & (t <= edges[j + 1])]
        cq = q.mean(axis=0)
        ax = np.linalg.eigh(np.cov((q - cq).T))[1][:, -1] if len(q) > 3 else axis
        tq = (q - cq) @ ax
        a, b = cq + np.quantile(tq, 0.15) * ax, cq + np.quantile(tq, 0.85) * ax
        caps.append((a, b, float(segment_distance(q, a, b).max())))
    return caps


def fit(p: np.ndarray, k: int = 1, slack: float = 0.005, seed: int = 0) -> list:
    """``k`` capsules of least total volume leaving no point of ``p`` more than ``slack`` outside."""
    rng = np.random.default_rng(seed)
    caps = _initial(p, k, rng)
    x0 = np.concatenate([np.r_[a, b, r] for a, b, r in caps])
    sub = p[rng.choice(len(p), size=min(len(p), 1500), replace=False)]

    def unpack(x):
        return [(x[7 * j:7 * j + 3], x[7 * j + 3:7 * j + 6], abs(x[7 * j + 6])) for j in range(k)]

    def cost(x):
        cs = unpack(x)
        over = np.maximum(outside(sub, cs) - slack, 0.0)
        return _volume(cs) + 50.0 * float(np.sum(over ** 2)) + 5.0 * float(over.max(initial=0.0))

    x = minimize(cost, x0, method="Powell", options={"maxiter": 20000, "xtol": 1e-4, "ftol": 1e-9}).x
    caps = unpack(x)
    # grow the radii until every point is within the slack
    for _ in range(50):
        d = outside(p, caps)
        if d.max() <= slack:
            break
        worst = p[np.argmax(d)]
        j = int(np.argmin([segment_distance(worst[None], a, b)[0] - r for a, b, r in caps]))
        a, b, r = caps[j]
        caps[j] = (a, b, r + d.max() - slack + 1e-4)
    return caps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", required=True)
    ap.add_argument("--link", action="append", default=[], help="name[:k capsules]; default: every link, k = 1")
    ap.add_argument("--kind", choices=("collision", "visual"), default="collision")
    ap.add_argument("--density", type=float, default=4.0e4, help="surface samples per m^2")
    ap.add_argument("--slack", type=float, default=0.005, help="farthest a sample may stay outside [m]")
    args = ap.parse_args()
    robot = RobotModel(args.robot)
    surf = link_surfaces(robot, args.kind, args.density)
    want = dict((s.split(":")[0], int(s.split(":")[1]) if ":" in s else 1) for s in args.link) or \
        {name: 1 for name in surf}
    np.set_printoptions(precision=3, suppress=True)
    for name, k in want.items():
        if name not in surf:
            raise SystemExit(f"{name}: no geometry (links with geometry: {sorted(surf)})")
        p = surf[name]
        caps = fit(p, k, args.slack)
        d = outside(p, caps)
        print(f"  {name}:   # {len(p)} samples, {np.mean(d <= 0) * 100:.0f} % inside, farthest {d.max():.3f} m out, "
              f"{_volume(caps) * 1e3:.2f} l")
        for j, (a, b, r) in enumerate(caps):
            a, b = np.round(a, 3) + 0.0, np.round(b, 3) + 0.0
            print(f"    - name: {name}_{j}\n      capsule: {{p0: {a.tolist()}, p1: {b.tolist()}, radius: {r:.3f}}}")


if __name__ == "__main__":
    main()
