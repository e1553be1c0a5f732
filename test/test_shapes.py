"""Collision model: loader validation, world shapes, exact segment distances, self-collision."""
from __future__ import annotations

import copy
import xml.etree.ElementTree as ET

import coal  # a dependency (tools/requirements.txt): missing, the tests fail, never skip
import numpy as np
import pinocchio as pin
import pytest
import yaml

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import (
    collision_model_from_dict,
    load_collision_model,
    point_segment_distance,
    segment_segment_distance,
)



@pytest.fixture(scope="module")
def doc(robot) -> dict:
    with open(robot.collision_path) as f:
        return yaml.safe_load(f)


def random_q(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    joints = rng.uniform(robot.lower, robot.upper)
    base = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))
    return robot.config(joints, base)


# ------------------------------------------------------------------ loading
def test_loads_the_shipped_model(cm):
    assert 20 <= cm.n_shapes <= 26
    assert len(set(cm.names)) == cm.n_shapes
    assert cm.n_pairs > 0
    assert cm.padding_m == 0.0
    assert cm.p0_local.shape == cm.p1_local.shape == (cm.n_shapes, 3)
    assert cm.pair_index.shape == (cm.n_pairs, 2)
    with pytest.raises(ValueError):
        cm.radii[0] = 1.0  # read-only
    for s in cm.shapes:
        assert (s.length == 0.0) == s.is_sphere
    # every shape kind of the file is present and the semantic YAML points at the file
    assert {s.kind for s in cm.shapes} == {"sphere", "capsule"}


def test_padding_override(robot, cm):
    padded = load_collision_model(robot.collision_path, robot, padding_m=0.02)
    np.testing.assert_allclose(padded.radii, cm.radii + 0.02)
    np.testing.assert_array_equal(padded.base_radii, cm.radii)
    assert padded.shapes == cm.shapes


def _expect_error(doc, robot, match, mutate):
    bad = copy.deepcopy(doc)
    mutate(bad)
    with pytest.raises(ValueError, match=match):
        collision_model_from_dict(bad, robot)


def test_unknown_link(doc, robot):
    _expect_error(doc, robot, "unknown link 'NO_SUCH_LINK'",
                  lambda d: d["links"].update(
                      NO_SUCH_LINK=[{"name": "x", "sphere": {"center": [0, 0, 0], "radius": 0.1}}]))


def test_negative_radius(doc, robot):
    def mutate(d):
        d["links"]["HEAD_LINK1"][0]["sphere"]["radius"] = -0.1
    _expect_error(doc, robot, r"'head'.*radius must be > 0", mutate)


def test_unknown_shape_in_pair(doc, robot):
    _expect_error(doc, robot, "unknown shape 'r_tentacle'",
                  lambda d: d["self_collision_pairs"].append(["r_tentacle", "head"]))


def test_duplicate_names(doc, robot):
    def mutate(d):
        d["links"]["LARM_LINK5"][0]["name"] = "r_hand"
    _expect_error(doc, robot, "duplicate shape name 'r_hand'", mutate)


@pytest.mark.parametrize(
    "match, mutate",
    [
        ("unknown top-level key", lambda d: d.update(pading_m=0.1)),
        ("padding_m must be >= 0", lambda d: d.update(padding_m=-0.01)),
        ("exactly one of", lambda d: d["links"]["HEAD_LINK1"][0].update(
            capsule={"p0": [0, 0, 0], "p1": [0, 0, 0.1], "radius": 0.1})),
        ("needs keys", lambda d: d["links"]["HEAD_LINK1"][0]["sphere"].pop("center")),
        (r"expected \[x, y, z\]", lambda d: d["links"]["HEAD_LINK1"][0]["sphere"].update(center=[0, 0])),
        ("expected a finite number", lambda d: d["links"]["HEAD_LINK1"][0]["sphere"].update(radius="big")),
        ("paired with itself", lambda d: d["self_collision_pairs"].append(["head", "head"])),
        ("listed twice", lambda d: d["self_collision_pairs"].append(list(reversed(d["self_collision_pairs"][0])))),
        ("both shapes are on link", lambda d: d["self_collision_pairs"].append(["chest_upper", "chest_lower"])),
        (r"expected \[shape, shape\]", lambda d: d["self_collision_pairs"].append(["head"])),
        ("missing or empty 'name'", lambda d: d["links"]["HEAD_LINK1"][0].pop("name")),
    ],
)
def test_other_validation_errors(doc, robot, match, mutate):
    _expect_error(doc, robot, match, mutate)


def test_loader_reports_the_file(doc, robot, tmp_path):
    bad = copy.deepcopy(doc)
    bad["links"]["HEAD_LINK1"][0]["sphere"]["radius"] = -1
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(ValueError, match="bad.yaml"):
        load_collision_model(path, robot)


# ------------------------------------------------------------------ world shapes
def test_world_shapes_follow_pinocchio_frames(robot):
    """A sphere at each link origin sits on the frame; a capsule end moves with it."""
    links = ["base_link", "CHEST_LINK1", "HEAD_LINK1", "RARM_LINK5", "LLEG_LINK5", "r_hand_ee"]
    p = [0.1, -0.2, 0.3]
    doc = {"links": {ln: [{"name": f"o_{ln}", "sphere": {"center": [0, 0, 0], "radius": 0.01}},
                          {"name": f"c_{ln}", "capsule": {"p0": [0, 0, 0], "p1": p, "radius": 0.02}}]
                     for ln in links}}
    m = collision_model_from_dict(doc, robot)
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = random_q(robot, rng)
        P0, P1, r = m.world_shapes(q)
        data = robot.forward(q)
        for ln in links:
            M = data.oMf[robot.frame_id(ln)]
            i, j = m.index(f"o_{ln}"), m.index(f"c_{ln}")
            np.testing.assert_allclose(P0[i], M.translation, atol=1e-12)
            np.testing.assert_allclose(P1[i], M.translation, atol=1e-12)
            np.testing.assert_allclose(P0[j], M.translation, atol=1e-12)
            np.testing.assert_allclose(P1[j], M.act(np.array(p)), atol=1e-12)
        np.testing.assert_allclose(r, [0.01, 0.02] * len(links))


def test_world_shapes_sources_and_batch(robot, cm):
    rng = np.random.default_rng(2)
    qs = np.array([random_q(robot, rng) for _ in range(4)])
    P0b, P1b, rb = cm.world_shapes_batch(qs)
    assert P0b.shape == (4, cm.n_shapes, 3)
    for n, q in enumerate(qs):
        P0, P1, r = cm.world_shapes(q)
        np.testing.assert_allclose(P0b[n], P0, atol=1e-12)
        np.testing.assert_allclose(P1b[n], P1, atol=1e-12)
        data = robot.forward(q)
        for src in (data, data.oMf):
            Q0, Q1, _ = cm.world_shapes(src)
            np.testing.assert_allclose(Q0, P0, atol=1e-12)
            np.testing.assert_allclose(Q1, P1, atol=1e-12)
        # reference: shape by shape with pinocchio's SE3
        for k, s in enumerate(cm.shapes):
            M = data.oMf[robot.frame_id(s.link)]
            np.testing.assert_allclose(P0[k], M.act(np.array(s.p0)), atol=1e-12)
            np.testing.assert_allclose(P1[k], M.act(np.array(s.p1)), atol=1e-12)
    d_batch = cm.self_distances(P0b, P1b, rb)
    assert d_batch.shape == (4, cm.n_pairs)
    for n, q in enumerate(qs):
        np.testing.assert_allclose(d_batch[n], cm.self_distances_at(q), atol=1e-12)
    hit = cm.in_self_collision(P0b, P1b, rb)
    assert hit.shape == (4,) and hit.dtype == bool
    with pytest.raises(ValueError):
        cm.world_shapes(qs[0][:-1])


@pytest.mark.parametrize("side", ["r", "l"])
def test_hand_capsule_stops_short_of_the_end_effector(robot, cm, side):
    rng = np.random.default_rng(3)
    k = cm.index(f"{side}_hand")
    for _ in range(3):
        q = random_q(robot, rng)
        P0, P1, r = cm.world_shapes(q)
        ee = robot.frame_pose(q, f"{side}_hand_ee").translation
        gap = point_segment_distance(ee, P0[k], P1[k])[0] - r[k]
        assert gap == pytest.approx(0.03, abs=1e-9)


# ------------------------------------------------------------------ segment distances
def _brute(a0, a1, b0, b1, n=401):
    s = np.linspace(0.0, 1.0, n)
    A = a0 + s[:, None] * (a1 - a0)
    B = b0 + s[:, None] * (b1 - b0)
    return np.sqrt(((A[:, None, :] - B[None, :, :]) ** 2).sum(-1)).min()


def _random_pairs(rng, n):
    """Random segment pairs: general, parallel, anti/collinear, near-parallel, degenerate."""
    out = []
    for k in range(n):
        a0, a1, b0, b1 = rng.normal(size=(4, 3))
        kind = k % 8
        if kind == 1:  # parallel, arbitrary overlap
            b1 = b0 + (a1 - a0) * rng.uniform(0.2, 2.0)
        elif kind == 2:  # anti-parallel
            b1 = b0 - (a1 - a0) * rng.uniform(0.2, 2.0)
        elif kind == 3:  # collinear
            d = a1 - a0
            b0, b1 = a0 + rng.uniform(-2, 2) * d, a0 + rng.uniform(-2, 2) * d
        elif kind == 4:  # nearly parallel
            b1 = b0 + (a1 - a0) + 1e-7 * rng.normal(size=3)
        elif kind == 5:  # sphere vs capsule
            a1 = a0.copy()
        elif kind == 6:  # sphere vs sphere
            a1, b1 = a0.copy(), b0.copy()
        elif kind == 7:  # crossing segments (zero distance)
            m = 0.5 * (a0 + a1)
            b0, b1 = m - rng.normal(size=3), None
            b1 = 2 * m - b0
        out.append((a0, a1, b0, b1))
    return out


def test_segment_distance_vs_dense_sampling():
    rng = np.random.default_rng(4)
    for a0, a1, b0, b1 in _random_pairs(rng, 160):
        d, s, t = segment_segment_distance(a0, a1, b0, b1)
        # the returned parameters realise the returned distance
        pa = a0 + s * (a1 - a0)
        pb = b0 + t * (b1 - b0)
        assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
        assert np.linalg.norm(pa - pb) == pytest.approx(float(d), abs=1e-12)
        # sampling never beats the exact minimum and comes within its resolution
        brute = _brute(a0, a1, b0, b1)
        h = (np.linalg.norm(a1 - a0) + np.linalg.norm(b1 - b0)) / 400
        assert d <= brute + 1e-12
        assert brute - d <= h + 1e-12


def _rot_z_to(d):
    z = d / np.linalg.norm(d)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _coal_shape(p0, p1, r):
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length == 0.0:
        return coal.Sphere(r), coal.Transform3s(np.eye(3), p0)
    return coal.Capsule(r, length), coal.Transform3s(_rot_z_to(d), 0.5 * (p0 + p1))


def test_capsule_distance_vs_coal():
    """Signed capsule / sphere distances equal coal's to 1e-9. Exception: nearly parallel
    segments (pair kind 4), where coal's capsule-capsule distance is off by up to ~1e-7
    (coal treats them as parallel); ours is realised by actual points on the segments
    (checked in the dense-sampling test), so it can only be smaller than coal's there."""
    rng = np.random.default_rng(5)
    pairs = _random_pairs(rng, 400)
    a0, a1, b0, b1 = (np.array(x) for x in zip(*pairs))
    ra = rng.uniform(0.01, 0.1, len(pairs))
    rb = rng.uniform(0.01, 0.1, len(pairs))
    d, _, _ = segment_segment_distance(a0, a1, b0, b1)  # vectorised over all pairs at once
    checked = 0
    for k in range(len(pairs)):
        if d[k] - ra[k] - rb[k] <= 1e-6:  # coal's penetration depth is another quantity
            continue
        ga, Ta = _coal_shape(a0[k], a1[k], ra[k])
        gb, Tb = _coal_shape(b0[k], b1[k], rb[k])
        dc = coal.distance(ga, Ta, gb, Tb, coal.DistanceRequest(), coal.DistanceResult())
        ours = d[k] - ra[k] - rb[k]
        if k % 8 == 4:
            assert dc - 1e-6 <= ours <= dc + 1e-12
        else:
            assert ours == pytest.approx(dc, abs=1e-9)
        checked += 1
    assert checked > 250


def test_segment_distance_exact_cases():
    x = np.array([1.0, 0.0, 0.0])
    o = np.zeros(3)
    up = np.array([0.0, 0.0, 0.3])
    # parallel overlapping, parallel disjoint (end to end), collinear gap, anti-parallel
    assert segment_segment_distance(o, x, up + 0.5 * x, up + 2 * x)[0] == pytest.approx(0.3, abs=1e-15)
    assert segment_segment_distance(o, x, up + 2 * x, up + 3 * x)[0] == pytest.approx(np.hypot(1, 0.3), abs=1e-15)
    assert segment_segment_distance(o, x, 1.5 * x, 3 * x)[0] == pytest.approx(0.5, abs=1e-15)
    assert segment_segment_distance(o, x, up + x, up)[0] == pytest.approx(0.3, abs=1e-15)
    # points and a point on a segment
    assert segment_segment_distance(o, o, up, up)[0] == pytest.approx(0.3, abs=1e-15)
    assert segment_segment_distance(0.5 * x, 0.5 * x, o, x)[0] == pytest.approx(0.0, abs=1e-15)
    # skew, perpendicular: closest points interior
    d, s, t = segment_segment_distance(-x, x, up + np.array([0, -1.0, 0]), up + np.array([0, 1.0, 0]))
    assert (d, s, t) == (pytest.approx(0.3, abs=1e-15), pytest.approx(0.5), pytest.approx(0.5))
    # nearly parallel: the distance is that of the lines at the overlap
    eps = np.array([0.0, 1e-12, 0.0])
    assert segment_segment_distance(o, x, up, up + x + eps)[0] == pytest.approx(0.3, abs=1e-12)
    # broadcasting: one segment against many
    many = np.stack([up + k * x for k in range(4)])
    d = segment_segment_distance(o, x, many, many + x)[0]
    np.testing.assert_allclose(d, [0.3, 0.3, np.hypot(1, 0.3), np.hypot(2, 0.3)], atol=1e-15)


# ------------------------------------------------------------------ postures
@pytest.mark.parametrize("posture", ["half_sitting", "zero"])
def test_no_self_collision_in_standard_postures(robot, cm, posture):
    q = robot.half_sitting() if posture == "half_sitting" else robot.config(np.zeros(robot.n_joints))
    P0, P1, r = cm.world_shapes(q)
    assert not cm.in_self_collision(P0, P1, r), cm.colliding_pairs(P0, P1, r)
    assert cm.self_distances(P0, P1, r).min() > 0.0


def test_nothing_below_the_floor_when_half_sitting(robot, cm):
    P0, P1, r = cm.world_shapes(robot.half_sitting())
    lowest = np.minimum(P0[:, 2], P1[:, 2]) - r
    assert lowest.min() >= -1e-9, dict(zip(cm.names, lowest.round(4)))
    # the feet come closest, but stay short of the sole
    feet = [cm.index(n) for n in cm.names if "_foot" in n]
    assert lowest[feet].max() < 0.01


def right_hand_in_chest(robot: RobotModel) -> np.ndarray:
    """Right arm raised forward (shoulder pitch -90 deg), upper arm rolled so that the elbow
    bends towards the body, elbow fully bent: the hand ends inside the chest."""
    deg = dict(robot.spec.half_sitting_deg)
    deg.update(RARM_JOINT0=-90, RARM_JOINT1=0, RARM_JOINT2=90, RARM_JOINT3=-130, RARM_JOINT4=0, RARM_JOINT5=0)
    joints = robot.joints_from_dict({k: np.radians(v) for k, v in deg.items()})
    assert robot.in_limits(joints)
    return robot.config(joints, robot.base_on_feet(joints))


def test_right_hand_in_chest_is_self_collision(robot, cm):
    q = right_hand_in_chest(robot)
    P0, P1, r = cm.world_shapes(q)
    assert cm.in_self_collision(P0, P1, r)
    hits = cm.colliding_pairs(P0, P1, r)
    assert any(a == "r_hand" and b.startswith(("chest", "backpack")) for a, b, _ in hits), hits
    assert all("r_" in a + b for a, b, _ in hits), hits  # the left side is not involved


# ------------------------------------------------------------------ coverage of the URDF
KNUCKLES = ("RLEG_LINK0", "RLEG_LINK1", "RLEG_LINK4", "LLEG_LINK0", "LLEG_LINK1", "LLEG_LINK4",
            "RARM_LINK4", "LARM_LINK4")


def _urdf_boxes(robot):
    out = {}
    for link in ET.fromstring(robot.urdf_xml).findall("link"):
        inertial, visual = link.find("inertial"), link.find("visual")
        if inertial is None or visual is None or visual.find("geometry/box") is None:
            continue
        mass = float(inertial.find("mass").get("value"))
        centre = np.array(visual.find("origin").get("xyz").split(), dtype=float)
        size = np.array(visual.find("geometry/box").get("size").split(), dtype=float)
        out[link.get("name")] = (mass, centre, size)
    return out


def test_every_massive_link_is_covered(robot, cm):
    """Coverage criterion, for every URDF link with mass > 0.4 kg except the hip, ankle and
    wrist knuckles: take the shapes carried by the link itself or by a link whose frame has
    the same origin (LINK0..2 of a shoulder, the chest joint: shapes there are unaffected
    by the joint between them). Then, at several postures, the link's box (the URDF
    visual = inertia box) has its centre inside these shapes, at least 65 % of its volume
    inside them (box edges and corners are rounded off) and no point farther than 6 cm
    from them (the chest box corners are the farthest, 5.3 cm)."""
    boxes = _urdf_boxes(robot)
    rng = np.random.default_rng(6)
    samples = rng.uniform(-0.5, 0.5, size=(4000, 3))
    postures = [robot.config(np.zeros(robot.n_joints)), robot.half_sitting(), random_q(robot, rng)]
    checked = set()
    for q in postures:
        data = robot.forward(q)
        P0, P1, r = cm.world_shapes(data)
        for link, (mass, centre, size) in boxes.items():
            if mass <= 0.4 or link in KNUCKLES:
                continue
            M = data.oMf[robot.frame_id(link)]
            group = [k for k, s in enumerate(cm.shapes)
                     if s.link == link or np.allclose(data.oMf[robot.frame_id(s.link)].translation, M.translation)]
            assert group, f"{link} ({mass} kg) carries no collision shape"
            pts = np.vstack([centre, centre + samples * size]) @ M.rotation.T + M.translation
            depth = np.min([point_segment_distance(pts, P0[k], P1[k])[0] - r[k] for k in group], axis=0)
            assert depth[0] <= 0.0, f"{link}: box centre outside its shapes"
            assert np.mean(depth <= 0.0) >= 0.65, f"{link}: only {np.mean(depth <= 0):.0%} of the box covered"
            assert depth.max() <= 0.06, f"{link}: box point {depth.max():.3f} m outside the shapes"
            checked.add(link)
    # waist, chest knuckle, chest, head, 2 x (shoulder knuckles x2, upper arm, forearm, hand),
    # 2 x (thigh, shank, foot)
    assert len(checked) == 20


def test_no_configured_pair_overlaps_by_construction(robot, cm):
    """A pair colliding at every posture (adjacent links) would make every check fail."""
    rng = np.random.default_rng(7)
    qs = np.array([robot.config(rng.uniform(robot.lower, robot.upper)) for _ in range(300)])
    d = cm.self_distances(*cm.world_shapes_batch(qs))
    always = np.all(d < 0.0, axis=0)
    assert not always.any(), [cm.pairs[k] for k in np.flatnonzero(always)]
    # and the sampled postures do produce self-collisions (the checker is not vacuous)
    assert 0.05 < np.mean(np.any(d < 0.0, axis=1)) < 0.9
