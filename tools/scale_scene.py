#!/usr/bin/env python3
"""A scene scaled for a smaller (or larger) robot: ``demo_scene`` of its robot.yaml
(docs/adding_a_robot.md).

    python tools/scale_scene.py config/scenes/plant.yaml OUT.yaml --xy 0.65 --z 0.82 --parts 1.0 --shift-x 0.1

Positions scale about the world origin (the floor midway between the soles): x and y by
``--xy``, z by ``--z`` (a robot's reach shrinks less in height than forwards when its legs
are long for its arms), then move forward by ``--shift-x`` (a robot whose hands hang further
forward needs the scene's nearest pipe further out). Sizes scale by ``--parts``: pipe and
sphere radii, box edges, the torus, the marker's printed size, and every primitive of the
target's group about the target's centre (the valve: hub, rim, spokes and stem keep their
shape, the rim stays round). Planes and the floor are unchanged. The output is the scene's
YAML document with these numbers (comments are not kept: write the new scene's header by
hand, saying how it was made). Keep ``--parts 1`` for a demo scene: the plant's pipes and
valve are real objects that do not shrink with the robot, and the marker's printed size and
place are what marker_localizer's parameters say (``marker_sizes_m``,
``marker_object_poses``); another ``--parts`` needs those changed to match.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from humanoid_reach_ros.sim.scene import scene_from_dict  # noqa: E402


def scale_scene(doc: dict, xy: float, z: float, parts: float, shift_x: float = 0.0) -> dict:
    """The scaled document (a new dict); ``doc`` as ``yaml.safe_load`` gives it."""
    S = np.array([xy, xy, z])
    shift = np.array([shift_x, 0.0, 0.0])
    centre = np.asarray(doc["target"]["position"], float)
    new_centre = centre * S + shift
    group = doc["target"].get("group", "valve")

    def place(p, in_group: bool) -> list[float]:
        p = np.asarray(p, float)
        q = new_centre + parts * (p - centre) if in_group else p * S + shift
        return [round(float(v), 6) for v in q]

    out = {k: v for k, v in doc.items() if k not in ("primitives", "target", "voxel_map")}
    prims = []
    for prim in doc["primitives"]:
        p = dict(prim)
        g = p.get("group") == group
        kind = p["type"]
        if kind == "box":
            p["center"] = place(p["center"], g)
            p["size"] = [round(float(s) * parts, 6) for s in p["size"]]
        elif kind == "cylinder":
            p["p0"], p["p1"] = place(p["p0"], g), place(p["p1"], g)
            p["radius"] = round(float(p["radius"]) * parts, 6)
        elif kind == "sphere":
            p["center"] = place(p["center"], g)
            p["radius"] = round(float(p["radius"]) * parts, 6)
        elif kind == "torus":
            p["center"] = place(p["center"], g)
            p["major_radius"] = round(float(p["major_radius"]) * parts, 6)
            p["minor_radius"] = round(float(p["minor_radius"]) * parts, 6)
        elif kind != "plane":
            raise ValueError(f"primitive {p.get('name')!r}: unknown type {kind!r}")
        prims.append(p)
    out["primitives"] = prims
    if "voxel_map" in doc:
        vm = dict(doc["voxel_map"])
        if "extent" in vm:
            vm["extent"] = {k: [round(float(v), 6) for v in np.asarray(vm["extent"][k], float) * S + shift]
                            for k in ("min", "max")}
        out["voxel_map"] = vm
    target = dict(doc["target"])
    target["position"] = [round(float(v), 6) for v in new_centre]
    if "aruco" in target:
        aruco = dict(target["aruco"])
        aruco["size_m"] = round(float(aruco["size_m"]) * parts, 6)
        aruco["position"] = [round(float(v) * parts, 6) for v in aruco.get("position", [0.0, 0.0, 0.0])]
        target["aruco"] = aruco
    out["target"] = target
    out["primitives"] = prims
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--xy", type=float, required=True, help="scale of x and y positions")
    ap.add_argument("--z", type=float, required=True, help="scale of heights")
    ap.add_argument("--parts", type=float, required=True, help="scale of sizes and of the target's group")
    ap.add_argument("--shift-x", type=float, default=0.0, help="forward shift after scaling [m]")
    ap.add_argument("--name", default=None, help="the new scene's name (default: the old name + '_scaled')")
    a = ap.parse_args(argv)
    for k in ("xy", "z", "parts"):
        v = getattr(a, k)
        if not (np.isfinite(v) and 0.1 <= v <= 10.0):
            ap.error(f"--{k} must be within [0.1, 10], got {v}")
    if not a.scene.is_file():
        ap.error(f"{a.scene}: no such file")
    doc = yaml.safe_load(a.scene.read_text())
    if not (np.isfinite(a.shift_x) and abs(a.shift_x) <= 2.0):
        ap.error(f"--shift-x must be within [-2, 2] m, got {a.shift_x}")
    out = scale_scene(doc, a.xy, a.z, a.parts, a.shift_x)
    out["name"] = a.name or f"{doc.get('name', 'scene')}_scaled"
    scene_from_dict(out, source=str(a.out))   # it must load
    a.out.write_text(yaml.safe_dump(out, sort_keys=False, default_flow_style=None, width=120))
    print(f"wrote {a.out}: target at {out['target']['position']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
