"""Scene primitives, loader, voxelization and ray casting (humanoid_reach_ros.sim.scene),
and the layout of the plant scene (config/scenes/plant.yaml) around the robot."""
from __future__ import annotations

import copy
import math

import numpy as np
import pinocchio as pin
import pytest
import yaml

from humanoid_reach_ros.geometry.sphere_tree import SphereTree
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model
from humanoid_reach_ros.sim.scene import (
    Box,
    Cylinder,
    Plane,
    Scene,
    Sphere,
    Torus,
    load_scene,
    rpy_to_matrix,
    scene_from_dict,
    voxel_center,
    voxel_index,
)

PLANT = "scenes/plant.yaml"
VALVE = (0.71, 0.03, 0.90)
PAPER_VOXELS = 22_753


@pytest.fixture(scope="module")
def plant() -> Scene:
    return load_scene(PLANT)


@pytest.fixture(scope="module")
def plant_doc() -> dict:
    with open(config_path(PLANT)) as f:
        return yaml.safe_load(f)


@pytest.fixture(scope="module")
def voxels(plant) -> np.ndarray:
    return plant.voxelize(0.02)


# ------------------------------------------------------------------ primitives
def test_rpy_matches_pinocchio():
    rng = np.random.default_rng(0)
    for rpy in rng.uniform(-3.0, 3.0, (20, 3)):
        assert np.allclose(rpy_to_matrix(rpy), pin.rpy.rpyToMatrix(*rpy), atol=1e-14)


def test_sdf_analytic_points():
    box = Box(name="b", center=(1.0, 0.0, 0.0), size=(0.2, 0.4, 0.6))
    p = np.array([[1.0, 0.0, 0.0], [1.3, 0.0, 0.0], [1.2, 0.3, 0.4], [1.05, 0.0, 0.0]])
    assert np.allclose(box.sdf(p), [-0.1, 0.2, math.sqrt(3) * 0.1, -0.05])
    rot = Box(name="r", center=(0.0, 0.0, 0.0), size=(0.2, 0.4, 0.6), rpy=(0.0, 0.0, math.pi / 2))
    assert rot.sdf(np.array([[0.3, 0.0, 0.0]]))[0] == pytest.approx(0.1)   # the 0.4 edge now along x
    lo, hi = rot.bounds()
    assert np.allclose(hi, [0.2, 0.1, 0.3])

    cyl = Cylinder(name="c", p0=(0.0, 0.0, 0.0), p1=(0.0, 0.0, 1.0), radius=0.1)
    p = np.array([[0.0, 0.0, 0.5], [0.3, 0.0, 0.5], [0.0, 0.0, 1.2], [0.4, 0.0, 1.4], [0.05, 0.0, 0.98]])
    assert np.allclose(cyl.sdf(p), [-0.1, 0.2, 0.2, 0.5, -0.02])
    sph = Sphere(name="s", center=(0.0, 1.0, 0.0), radius=0.2)
    assert np.allclose(sph.sdf(np.array([[0.0, 1.0, 0.0], [0.0, 1.5, 0.0]])), [-0.2, 0.3])
    tor = Torus(name="t", center=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0), major_radius=0.12, minor_radius=0.01)
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.12, 0.0], [0.05, 0.0, 0.12], [0.0, 0.0, -0.2]])
    assert np.allclose(tor.sdf(p), [0.11, -0.01, 0.04, 0.07])
    plane = Plane(name="f", normal=(0.0, 0.0, 1.0), offset=0.0)
    assert np.allclose(plane.sdf(np.array([[5.0, 3.0, 0.2], [0.0, 0.0, -0.1]])), [0.2, -0.1])


@pytest.mark.parametrize("prim", [
    Box(name="b", center=(0.1, -0.2, 0.3), size=(0.3, 0.2, 0.5), rpy=(0.3, -0.2, 0.7)),
    Cylinder(name="c", p0=(0.0, 0.1, 0.2), p1=(0.4, -0.3, 0.6), radius=0.08),
    Sphere(name="s", center=(0.2, 0.2, 0.2), radius=0.15),
    Torus(name="t", center=(0.0, 0.0, 0.3), axis=(0.6, 0.0, 0.8), major_radius=0.2, minor_radius=0.05),
])
def test_sdf_is_a_distance(prim):
    """Outside: a 1-Lipschitz function whose value is attained (p - sdf * grad is on the surface)."""
    rng = np.random.default_rng(1)
    p = rng.uniform(-0.6, 0.9, (4000, 3))
    s = prim.sdf(p)
    q = rng.uniform(-0.6, 0.9, (4000, 3))
    assert np.all(np.abs(prim.sdf(q) - s) <= np.linalg.norm(q - p, axis=1) + 1e-12)
    eps = 1e-6
    g = np.stack([(prim.sdf(p + e) - prim.sdf(p - e)) / (2 * eps) for e in np.eye(3) * eps], axis=1)
    out = s > 1e-3
    surf = p[out] - s[out, None] * g[out]
    assert np.allclose(prim.sdf(surf), 0.0, atol=1e-6)
    lo, hi = prim.bounds()
    inside = p[s < 0]
    assert np.all(inside >= lo - 1e-12) and np.all(inside <= hi + 1e-12)


# ------------------------------------------------------------------ loader
def _doc_with(plant_doc, k, **changes):
    doc = copy.deepcopy(plant_doc)
    doc["primitives"][k].update(changes)
    return doc


def _index(plant_doc, name):
    return next(i for i, p in enumerate(plant_doc["primitives"]) if p["name"] == name)


@pytest.mark.parametrize("name,changes,match", [
    ("passage_pipe", {"type": "pyramid"}, "unknown type 'pyramid'"),
    ("passage_pipe", {"radius": -0.05}, "radius: must be > 0"),
    ("passage_pipe", {"radius": float("nan")}, "finite number"),
    ("passage_pipe", {"p1": [0.35, -0.85, 0.72]}, "zero-length"),
    ("passage_pipe", {"p1": [0.35, float("inf"), 0.72]}, "finite number"),
    ("passage_pipe", {"diameter": 0.1}, "unknown key"),
    ("passage_support_left", {"size": [0.1, -0.06, 0.67]}, "size must be positive"),
    ("passage_support_left", {"center": [0.1, 0.2]}, "expected \\[x, y, z\\]"),
    ("valve_rim", {"minor_radius": 0.2}, "minor_radius"),
    ("valve_rim", {"axis": [0.0, 0.0, 0.0]}, "non-zero"),
    ("floor", {"floor": "yes"}, "floor must be true or false"),
    ("floor", {"color": [1.0, 2.0, 0.0]}, "color"),
])
def test_loader_rejects_bad_entries(plant_doc, name, changes, match):
    doc = _doc_with(plant_doc, _index(plant_doc, name), **changes)
    with pytest.raises(ValueError, match=match) as err:
        scene_from_dict(doc, source="test.yaml")
    assert repr(name) in str(err.value)   # the message names the entry


def test_loader_rejects_structure(plant_doc):
    doc = copy.deepcopy(plant_doc)
    del doc["primitives"][_index(doc, "valve_rim")]["major_radius"]
    with pytest.raises(ValueError, match="valve_rim.*major_radius"):
        scene_from_dict(doc)
    doc = copy.deepcopy(plant_doc)
    doc["primitives"].append(copy.deepcopy(doc["primitives"][1]))
    with pytest.raises(ValueError, match="duplicate name 'passage_pipe'"):
        scene_from_dict(doc)
    for key, value, match in (("extras", 1, "unknown top-level"), ("primitives", [], "non-empty list"),
                              ("voxel_map", {"resolution_m": 0.0}, "resolution_m"),
                              ("voxel_map", {"extent": {"min": [0, 0, 0], "max": [1, -1, 1]}}, "below max"),
                              ("target", {"name": "v"}, "target"),
                              ("target", {"name": "v", "position": [0, 0, 0], "aruco": {"id": -1}}, "aruco")):
        doc = copy.deepcopy(plant_doc)
        doc[key] = value
        with pytest.raises(ValueError, match=match):
            scene_from_dict(doc)
    with pytest.raises(ValueError, match="missing or empty 'name'"):
        scene_from_dict({"primitives": [{"type": "sphere", "center": [0, 0, 0], "radius": 1.0}]})


# ------------------------------------------------------------------ the plant scene
def test_plant_target_and_marker(plant):
    t = plant.target
    assert t.name == "red_valve"
    assert np.allclose(t.position, VALVE, atol=0.0)
    assert np.allclose(plant.primitive("valve_rim").center, VALVE, atol=0.0)
    assert t.aruco.marker_id == 7 and t.aruco.size_m == pytest.approx(0.10)
    M = t.marker_pose
    assert np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.allclose(M[:3, 2], [-1.0, 0.0, 0.0], atol=1e-12)     # faces the robot (-x)
    assert np.allclose(M[:3, 1], [0.0, 0.0, 1.0], atol=1e-12)      # upright
    # the marker lies on the hub plate's front face, and its square on the plate
    corners = M[:3, 3] + np.array([[sx, sy, 0.0] for sx in (-0.05, 0.05) for sy in (-0.05, 0.05)]) @ M[:3, :3].T
    plate = plant.primitive("valve_hub_plate")
    assert np.allclose(plate.sdf(np.vstack([M[:3, 3], corners])), 0.0, atol=1e-9)
    # visible from the head camera: nothing crosses the lines of sight to its corners
    cam = np.array([0.113, 0.0, 1.449])
    d = np.vstack([M[:3, 3], corners]) - cam
    t_hit = plant.raycast(np.broadcast_to(cam, d.shape), d)
    assert np.allclose(t_hit, np.linalg.norm(d, axis=1), atol=1e-6)


def test_plant_voxel_counts(plant, voxels):
    assert plant.resolution_m == 0.02
    assert abs(len(voxels) - PAPER_VOXELS) <= 0.03 * PAPER_VOXELS    # 22,532 at 0.02 m
    fine = plant.voxelize(0.015)
    assert 35_000 <= len(fine) <= 48_000                              # 41,513 at 0.015 m
    # on the grid: centres at (i + 1/2) h, inside the extent, unique, floor excluded
    k = voxels / 0.02 - 0.5
    assert np.allclose(k, np.round(k), atol=1e-9)
    assert np.array_equal(voxel_center(voxel_index(voxels, 0.02), 0.02), voxels)
    lo, hi = (np.array(v) for v in plant.extent)
    assert np.all(voxels >= lo) and np.all(voxels <= hi)
    assert len(np.unique(voxels, axis=0)) == len(voxels)
    with_floor = plant.voxelize(0.02, include_floor=True)
    assert len(with_floor) > len(voxels) + 5000


def test_voxelize_equals_full_grid(plant):
    """Candidate-based voxelization equals evaluating the union SDF on every cell."""
    h = 0.04
    band = h * math.sqrt(3) / 2
    lo, hi = (np.array(v) for v in plant.extent)
    axes = [np.arange(math.ceil(a / h - 0.5), math.floor(b / h - 0.5) + 1) for a, b in zip(lo, hi)]
    grid = (np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3) + 0.5) * h
    s = plant.sdf(grid, include_floor=False)
    for surface in (True, False):
        want = grid[(np.abs(s) <= band) if surface else (s <= band)]
        got = plant.voxelize(h, surface_only=surface)
        assert np.array_equal(_sorted(got), _sorted(want))
    without_valve = plant.voxelize(h, exclude_groups=("valve",))
    s2 = plant.sdf(grid, include_floor=False, exclude_groups=("valve",))
    assert np.array_equal(_sorted(without_valve), _sorted(grid[np.abs(s2) <= band]))


def _sorted(v: np.ndarray) -> np.ndarray:
    return v[np.lexsort(v.T[::-1])]


@pytest.mark.parametrize("h", [0.02, 0.015])
def test_voxelize_single_sphere_matches_analytic(h):
    c, R = np.array([0.013, -0.207, 0.5]), 0.137
    scene = Scene(name="ball", primitives=(Sphere(name="s", center=tuple(c), radius=R),),
                  extent=((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0)))
    band = h * math.sqrt(3) / 2
    i = np.arange(math.floor((c.min() - R - 2 * h) / h), math.ceil((c.max() + R + 2 * h) / h) + 1)
    grid = (np.stack(np.meshgrid(i, i, i, indexing="ij"), -1).reshape(-1, 3) + 0.5) * h
    dist = np.linalg.norm(grid - c, axis=1) - R
    for surface, want in ((True, grid[np.abs(dist) <= band]), (False, grid[dist <= band])):
        got = scene.voxelize(h, surface_only=surface)
        assert np.array_equal(_sorted(got), _sorted(want))
    # the surface shell is about 1.7 voxels thick: count ~ 4 pi R^2 sqrt(3) h / h^3
    assert len(scene.voxelize(h)) == pytest.approx(4 * math.pi * R**2 * math.sqrt(3) / h**2, rel=0.15)


def test_voxelize_extent_and_validation(plant):
    part = plant.voxelize(0.02, extent=((0.5, -0.2, 0.6), (1.0, 0.3, 1.2)))
    full = plant.voxelize(0.02)
    inside = np.all((full >= [0.5, -0.2, 0.6]) & (full <= [1.0, 0.3, 1.2]), axis=1)
    assert np.array_equal(_sorted(part), _sorted(full[inside]))
    assert len(plant.voxelize(0.02, extent=((5.0, 5.0, 5.0), (5.001, 5.001, 5.001)))) == 0
    with pytest.raises(ValueError):
        plant.voxelize(-0.02)
    with pytest.raises(ValueError):
        plant.voxelize(0.02, extent=((0.0, 0.0), (1.0, 1.0)))


def _link_boxes(robot: RobotModel, q: np.ndarray, n: int = 5) -> np.ndarray:
    """Points filling every URDF link box (visual geometry) at posture q."""
    geom = pin.buildGeomFromUrdfString(robot.model, robot.urdf_xml, pin.GeometryType.VISUAL)
    gdata = pin.GeometryData(geom)
    robot.forward(q)
    pin.updateGeometryPlacements(robot.model, robot.data, geom, gdata, q)
    unit = np.stack(np.meshgrid(*[np.linspace(-1, 1, n)] * 3, indexing="ij"), -1).reshape(-1, 3)
    pts = []
    for k, obj in enumerate(geom.geometryObjects):
        M = gdata.oMg[k]
        pts.append((unit * np.asarray(obj.geometry.halfSide)) @ M.rotation.T + M.translation)
    return np.vstack(pts)


def test_plant_clear_of_half_sitting_robot(plant, voxels, robot):
    q = robot.half_sitting()
    data = robot.forward(q)
    origins = np.array([M.translation for M in data.oMf])
    # no voxel within 5 cm of any link / joint frame origin (sole frames: floor excluded)
    tree = SphereTree.from_voxels(voxels, 0.02)
    d = tree.min_distance_batch(origins, origins, 0.0)
    assert d.min() > 0.05
    # every primitive >= 5 cm from every URDF link box, >= 10 cm from the skeleton
    boxes = _link_boxes(robot, q)
    assert plant.sdf(boxes, include_floor=False).min() > 0.05
    m = robot.model
    pin.forwardKinematics(m, data, q)
    segs = [(data.oMi[m.parents[j]].translation, data.oMi[j].translation) for j in range(2, m.njoints)]
    t = np.linspace(0.0, 1.0, 25)[:, None]
    skeleton = np.vstack([a + t * (b - a) for a, b in segs])
    assert plant.sdf(skeleton, include_floor=False).min() > 0.10
    # and the robot's collision shapes are clear of the voxel spheres
    shapes = load_collision_model(None, robot)
    P0, P1, R = shapes.world_shapes(q)
    assert tree.min_distance_batch(P0, P1, R).min() > 0.03
    assert not tree.any_intersection(P0, P1, R)


def test_plant_valve_vicinity_is_free(plant):
    """Only the valve's own parts and its supply pipe come within 0.25 m of its centre."""
    centre = np.array([VALVE])
    allowed = {p.name for p in plant.primitives if p.group == "valve"} | {"valve_supply_pipe"}
    for p in plant.select(include_floor=False):
        if p.name not in allowed:
            assert p.sdf(centre)[0] > 0.25, p.name
    # the wheel's centre itself is open (the hand's goal point)
    assert plant.sdf(centre)[0] > 0.03


def test_plant_layout_intent(plant, robot):
    """The narrow passage in front of the lower body (right arm, Fig. 5) and the pipe at
    the left shoulder (left arm, Fig. 6)."""
    q = robot.half_sitting()
    shapes = load_collision_model(None, robot)
    P0, P1, R = shapes.world_shapes(q)

    def gap(shape: str, prim: str) -> float:
        k = shapes.index(shape)
        t = np.linspace(0.0, 1.0, 50)[:, None]
        pts = P0[k] + t * (P1[k] - P0[k])
        return float(plant.primitive(prim).sdf(pts).min() - R[k])

    passage = min(gap(s, "passage_pipe") for s in ("waist", "r_thigh", "l_thigh", "abdomen"))
    assert 0.15 <= passage <= 0.25
    pipe = plant.primitive("passage_pipe")
    hand = data_hand = robot.frame_pose(q, "r_hand_ee").translation
    assert pipe.p0[2] + pipe.radius > hand[2] + 0.1      # the hanging hand is below the pipe's top
    del data_hand
    shoulder = robot.frame_pose(q, "LARM_LINK0").translation
    left = plant.primitive("left_shoulder_pipe")
    assert abs(left.p0[2] - shoulder[2]) < 0.05          # at shoulder height
    assert left.p0[1] > shoulder[1] and left.p1[0] > left.p0[0] > shoulder[0]   # ahead, left, along x
    assert 0.05 < gap("l_shoulder", "left_shoulder_riser") < 0.2
    # leaning forward at the half-sitting height puts the left shoulder into it
    ahead = shoulder + np.array([0.25, -0.03, -0.06])
    r_sh = R[shapes.index("l_shoulder")]
    assert left.sdf(ahead[None])[0] < r_sh


# ------------------------------------------------------------------ ray casting
def test_raycast_analytic_cases():
    scene = Scene(name="rays", primitives=(
        Plane(name="floor", normal=(0.0, 0.0, 1.0), offset=0.0, floor=True),
        Sphere(name="ball", center=(2.0, 0.0, 1.0), radius=0.5),
        Box(name="box", center=(0.0, 2.0, 1.0), size=(0.4, 0.4, 0.4)),
        Cylinder(name="pipe", p0=(-2.0, -1.0, 1.0), p1=(2.0, -1.0, 1.0), radius=0.1),
        Torus(name="wheel", center=(0.0, -3.0, 1.0), axis=(0.0, 1.0, 0.0), major_radius=0.3, minor_radius=0.05),
    ))
    o = np.array([0.0, 0.0, 1.0])
    dirs = np.array([
        [0.0, 0.0, -1.0],     # floor at 1.0
        [1.0, 0.0, 0.0],      # ball at 1.5
        [0.0, 1.0, 0.0],      # box face at 1.8
        [0.0, -1.0, 0.0],     # pipe side at 0.9
        [0.0, 0.0, 1.0],      # nothing
        [0.0, 3.0, 0.0],      # unnormalised: box at 1.8 m
    ])
    t, k = scene.raycast(np.broadcast_to(o, dirs.shape), dirs, return_index=True)
    assert np.allclose(t[[0, 1, 2, 3, 5]], [1.0, 1.5, 1.8, 0.9, 1.8], atol=1e-12)
    assert t[4] == np.inf and k[4] == -1
    assert [scene.primitives[i].name for i in k[[0, 1, 2, 3]]] == ["floor", "ball", "box", "pipe"]
    # along the pipe's axis from outside: its cap; from inside: 0
    assert scene.raycast([-3.0, -1.0, 1.0], [1.0, 0.0, 0.0])[0] == pytest.approx(1.0)
    assert scene.raycast([0.0, -1.0, 1.0], [1.0, 0.0, 0.0])[0] == 0.0
    # through the wheel's hole (misses it, hits nothing else) and onto its tube
    assert scene.raycast([0.0, -2.0, 1.0], [0.0, -1.0, 0.0], include_floor=False)[0] == np.inf
    assert scene.raycast([0.3, -2.0, 1.0], [0.0, -1.0, 0.0])[0] == pytest.approx(0.95, abs=1e-6)
    assert scene.raycast([0.0, -3.0, 3.0], [0.0, 0.0, -1.0])[0] == pytest.approx(2.0 - 0.35, abs=1e-6)
    # max range and floor exclusion
    assert scene.raycast(o, [0.0, 0.0, -1.0], max_range=0.5)[0] == np.inf
    assert scene.raycast(o, [0.0, 0.0, -1.0], include_floor=False)[0] == np.inf
    with pytest.raises(ValueError):
        scene.raycast(o, [0.0, 0.0, 0.0])


@pytest.mark.parametrize("prim", [
    Plane(name="p", normal=(0.3, -0.2, 0.9), offset=0.1),
    Box(name="b", center=(0.1, -0.2, 0.3), size=(0.3, 0.2, 0.5), rpy=(0.3, -0.2, 0.7)),
    Cylinder(name="c", p0=(0.0, 0.1, 0.2), p1=(0.4, -0.3, 0.6), radius=0.08),
    Sphere(name="s", center=(0.2, 0.2, 0.2), radius=0.15),
    Torus(name="t", center=(0.0, 0.0, 0.3), axis=(0.6, 0.0, 0.8), major_radius=0.2, minor_radius=0.05),
])
def test_primitive_ray_entry_matches_marching(prim):
    """Rays from everywhere (some inside): entry on the surface (or 0 inside), nothing before it."""
    rng = np.random.default_rng(9)
    n, far = 300, 3.0
    o = rng.uniform(-0.5, 0.8, (n, 3))
    target = rng.uniform(-0.2, 0.5, (n, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = prim.ray_entry(o, d)
    inside = prim.sdf(o) <= 0.0
    assert np.all(t[inside] == 0.0)
    hit = np.isfinite(t) & ~inside
    assert hit.sum() > 20
    assert np.allclose(prim.sdf(o[hit] + t[hit, None] * d[hit]), 0.0, atol=1e-6)
    steps = np.linspace(0.0, 1.0, 2001)[:-1]
    for i in np.flatnonzero(~inside):
        end = t[i] if np.isfinite(t[i]) else far
        assert prim.sdf(o[i] + (steps[:, None] * end) * d[i]).min() > -1e-9, i


def test_raycast_matches_marching(plant):
    """Random rays from the head: the hit is on the surface, and no sample before it is inside."""
    rng = np.random.default_rng(4)
    n = 400
    o = np.array([0.11, 0.0, 1.45]) + rng.normal(0.0, 0.05, (n, 3))
    d = rng.normal(size=(n, 3)) + [1.0, 0.0, -0.3]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = plant.raycast(o, d, max_range=4.0)
    hit = np.isfinite(t)
    assert 0.5 * n < hit.sum() < n
    assert np.allclose(plant.sdf(o[hit] + t[hit, None] * d[hit]), 0.0, atol=1e-6)
    steps = np.linspace(0.0, 1.0, 801)
    for i in range(n):
        end = t[i] if hit[i] else 4.0
        s = plant.sdf(o[i] + (steps[:-1, None] * end) * d[i])
        assert s.min() > -1e-9, i


def test_normals(plant):
    p = np.array([[0.35, 0.0, 0.72 + 0.05 + 0.01]])   # just above the passage pipe
    assert np.allclose(plant.normals(p), [[0.0, 0.0, 1.0]], atol=1e-6)
