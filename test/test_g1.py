"""The third humanoid, the Unitree G1 (config/robots/g1, issue 23), added from its files alone:
the description loads from example-robot-data's URDF with the frames it adds (soles and grasp
points measured on the meshes, the depth camera's optical frame), the stance is level and
symmetric, the camera looks forward and down, half-sitting is balanced, the collision model
covers the meshes and half-sitting is free of self-collision. The limbs' IK (numerical:
kinematics/numerical_ik.py) and planning are test_numerical_ik's and the planner's tests, not these."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial import ConvexHull

from humanoid_reach_ros.dual_arm.balance import polygon_margin, support_polygon
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model, point_segment_distance

ARMS = ("right_arm", "left_arm")
LEGS = ("right_leg", "left_leg")
SWAP = {"r_": "l_", "l_": "r_"}


@pytest.fixture(scope="module")
def g1():
    return RobotModel("g1")


@pytest.fixture(scope="module")
def cm(g1):
    return load_collision_model(None, g1)


@pytest.fixture(scope="module")
def visual(g1):
    """The URDF's visual geometry (its collision geometry leaves out the pelvis, waist and hands
    and has the feet as four 5 mm spheres: collision.yaml covers the visual meshes)."""
    return pin.buildGeomFromUrdfString(g1.model, g1.urdf_xml, pin.GeometryType.VISUAL,
                                       package_dirs=[str(d) for d in g1.spec.package_dirs])


def _vertices(obj) -> np.ndarray:
    """A mesh's vertices in the frame of the joint it moves with."""
    v = np.asarray(obj.geometry.vertices())
    return v @ obj.placement.rotation.T + obj.placement.translation


def _mesh(g1, visual, link) -> np.ndarray:
    """Vertices of ``link``'s visual mesh in the frame of the joint it moves with."""
    objs = [o for o in visual.geometryObjects if o.name.startswith(link + "_")]
    assert len(objs) == 1, [o.name for o in visual.geometryObjects]
    return _vertices(objs[0])


def _inside_hull(points, x) -> np.ndarray:
    """Whether each point of ``x`` lies in the convex hull of ``points`` (2-D or 3-D)."""
    eq = ConvexHull(points).equations
    return np.all(np.asarray(x) @ eq[:, :-1].T + eq[:, -1] <= 1e-12, axis=1)


def _in_frame(g1, frame, v) -> np.ndarray:
    """Points of the frame's joint frame expressed in ``frame``."""
    F = g1.model.frames[g1.frame_id(frame)].placement
    return (v - F.translation) @ F.rotation


# ------------------------------------------------------------------ the description
def test_the_description_loads_from_the_packaged_urdf(g1):
    spec = g1.spec
    assert spec.urdf_path.name == "g1_29dof_rev_1_0.urdf" and spec.urdf_path.is_file()
    assert "example-robot-data" in spec.urdf_path.parts and len(spec.package_dirs) == 1
    assert g1.n_joints == 29 and g1.model.nq == 36
    assert [len(g1.limbs[n].joints) for n in (*LEGS, *ARMS)] == [6, 6, 7, 7]
    # no neck, no gripper; the waist's three joints by role: yaw about z, pitch about y, roll about x
    assert not spec.has_neck and spec.neck_joints == () and spec.gripper_joints == ()
    m = g1.model
    kind = {j: m.joints[m.getJointId(j)].shortname() for j in spec.torso_joints}
    assert [kind[spec.chest_yaw], kind[spec.chest_pitch], kind[spec.chest_roll]] == \
        ["JointModelRZ", "JointModelRY", "JointModelRX"]
    assert spec.chest_joints == (spec.chest_yaw, spec.chest_pitch) and len(spec.torso_joints) == 3


def test_the_added_frames_hang_from_the_limb_ends_and_reach_the_robot_description(g1):
    spec = g1.spec
    assert set(spec.frames) == {*g1.sole_frames, *g1.hand_frames.values(), g1.camera_frame}
    for limb in (*LEGS, *ARMS):   # the soles on the ankle roll joint, the grasp points on the wrist yaw joint
        f = g1.model.frames[g1.frame_id(g1.limbs[limb].tip)]
        assert g1.model.names[f.parentJoint] == g1.limbs[limb].joints[-1]
    model = pin.buildModelFromXML(g1.description_xml, pin.JointModelFreeFlyer())
    data = model.createData()
    q = g1.half_sitting()
    pin.framesForwardKinematics(model, data, q)
    for name in spec.frames:   # the fixed joints' origins are written to 9 digits: the rpy of +-pi/2 to 1e-9
        assert name not in g1.urdf_xml and f'<link name="{name}"' in g1.description_xml
        np.testing.assert_allclose(data.oMf[model.getFrameId(name)].homogeneous,
                                   g1.frame_pose(q, name).homogeneous, atol=1e-8)


@pytest.mark.parametrize("leg", LEGS)
def test_the_sole_frame_is_on_the_foot_mesh_bottom_and_its_rectangle_inside_the_outline(g1, visual, leg):
    joint = g1.limbs[leg].joints[-1]
    link = g1.model.frames[g1.model.getFrameId(joint.replace("_joint", "_link"))].name
    v = _in_frame(g1, g1.limbs[leg].tip, _mesh(g1, visual, link))
    assert abs(v[:, 2].min()) < 2e-4                       # the sole plane is the mesh's bottom face
    bottom = v[v[:, 2] < 1e-3, :2]
    x0, x1, y0, y1 = g1.spec.sole_rectangle
    corners = np.array([[x0, y0], [x0, y1], [x1, y0], [x1, y1]])
    assert _inside_hull(bottom, corners).all()
    # the frame is centred on the outline (within 5 mm), the rectangle on the frame
    assert abs(bottom[:, 0].min() + bottom[:, 0].max()) < 0.01 and abs(bottom[:, 1].mean()) < 0.005
    assert x0 == -x1 and y0 == -y1


@pytest.mark.parametrize("arm", ARMS)
def test_the_grasp_point_is_in_the_hollow_of_the_hand(g1, visual, arm):
    """Inside the rubber hand's hull, at least 0.025 m from its surface (palm, fingers and thumb
    around it), its z axis up the forearm (the wrist's -x), its y the wrist's y."""
    side = arm.split("_")[0]
    v = _mesh(g1, visual, f"{side}_rubber_hand")
    G = g1.model.frames[g1.frame_id(g1.hand_frames[side])].placement
    assert _inside_hull(v, G.translation[None])[0]
    assert np.linalg.norm(v - G.translation, axis=1).min() > 0.025
    np.testing.assert_allclose(G.rotation, [[0, 0, -1], [0, 1, 0], [1, 0, 0]], atol=1e-12)


def test_half_sitting_stance_is_level_symmetric_and_knees_bent(g1):
    q = g1.half_sitting()
    r, l_ = (g1.frame_pose(q, f) for f in g1.sole_frames)
    for s in (r, l_):
        np.testing.assert_allclose(s.rotation, np.eye(3), atol=1e-9)
        assert abs(s.translation[2]) < 1e-9
    np.testing.assert_allclose(r.translation * [1, -1, 1], l_.translation, atol=1e-9)
    assert r.translation[1] < 0 < l_.translation[1]
    np.testing.assert_allclose(g1.base_pose(q).rotation, np.eye(3), atol=1e-9)
    # the pelvis 0.05 .. 0.08 m lower than on straight legs
    straight = np.zeros(g1.n_joints)
    drop = g1.base_on_feet(straight).translation[2] - q[2]
    assert 0.05 < drop < 0.08, drop
    # the hands mirror each other (to the URDF's asymmetry: the shoulders' offsets differ by 1e-5 m,
    # their mounting angles by 2e-4 rad), in front of the thighs (ahead of the knees), above the knees
    hr, hl = (g1.frame_pose(q, g1.hand_frames[s]) for s in ("right", "left"))
    np.testing.assert_allclose(hr.translation * [1, -1, 1], hl.translation, atol=1e-4)
    np.testing.assert_allclose(hr.rotation, np.diag([1, -1, 1]) @ hl.rotation @ np.diag([1, -1, 1]), atol=1e-3)
    knee = g1.frame_pose(q, g1.limbs["left_leg"].joints[3].replace("_joint", "_link")).translation
    assert hl.translation[0] > knee[0] + 0.05 and hl.translation[2] > knee[2] + 0.15


def test_the_camera_frame_is_an_optical_frame_looking_forward_and_down(g1):
    M = g1.frame_pose(g1.half_sitting(), g1.camera_frame)
    x, y, z = M.rotation.T   # its axes in the world: z forward and down, x right (-y world), y down
    assert z @ [1, 0, 0] > 0.6 and z @ [0, 0, -1] > 0.6 and abs(z[1]) < 1e-9
    assert x @ [0, -1, 0] > 0.99 and y @ [0, 0, -1] > 0.6
    assert 1.1 < M.translation[2] < 1.3


def test_base_on_feet_keeps_the_right_sole_at_its_stance(g1):
    rng = np.random.default_rng(3)
    hs = g1.half_sitting_joints
    base = g1.base_on_feet(hs)   # half-sitting: the pelvis upright above the middle of the soles
    np.testing.assert_allclose(base.rotation, np.eye(3), atol=1e-9)
    assert abs(base.translation[1]) < 1e-9
    for _ in range(5):
        j = np.clip(hs + rng.normal(0, 0.2, g1.n_joints), g1.lower, g1.upper)
        q = g1.config(j, g1.base_on_feet(j))
        sole = g1.frame_pose(q, g1.sole_frames[0])
        np.testing.assert_allclose(sole.homogeneous, g1.stance_soles[0].homogeneous, atol=1e-9)


def test_half_sitting_com_is_inside_the_support_polygon(g1):
    poly = support_polygon(g1)
    x0, x1, y0, y1 = g1.spec.sole_rectangle
    width = g1.stance_soles[1].translation[1] - g1.stance_soles[0].translation[1]
    np.testing.assert_allclose(np.ptp(poly, axis=0), [x1 - x0, width + y1 - y0], atol=1e-9)
    margin = polygon_margin(poly, g1.com(g1.half_sitting())[:2])[0]
    assert margin > 0.05, margin


# ------------------------------------------------------------------ collision model
#: a mesh point may be this far outside the shapes (as Talos's; the trunk's back corners: 0.019 m)
COVER_TOL_M = 0.035
#: the hand shapes end this far short of the grasp point: the palm and fingers beyond are not covered
GRASP_CLEARANCE_M = 0.03


def test_the_collision_model_covers_the_meshes(g1, cm, visual):
    gdata = pin.GeometryData(visual)
    meshes = [(k, o.parentJoint, np.asarray(o.geometry.vertices())) for k, o in enumerate(visual.geometryObjects)]
    grasp = {g1.model.frames[g1.frame_id(f)].parentJoint: g1.frame_id(f) for f in g1.hand_frames.values()}
    rng = np.random.default_rng(8)
    postures = ([g1.half_sitting(), g1.config(np.zeros(g1.n_joints))]
                + [g1.config(rng.uniform(g1.lower, g1.upper)) for _ in range(3)])
    checked, worst = 0, 0.0
    for q in postures:
        data = g1.forward(q)
        pin.updateGeometryPlacements(g1.model, data, visual, gdata, q)
        P0, P1, r = cm.world_shapes(data)
        for k, joint, v in meshes:
            M = gdata.oMg[k]
            w = v @ M.rotation.T + M.translation
            if joint in grasp:   # the hand: points at least the clearance up the forearm from the grasp point
                G = data.oMf[grasp[joint]]
                w = w[(w - G.translation) @ G.rotation[:, 2] >= GRASP_CLEARANCE_M]
            d = np.min([point_segment_distance(w, P0[s], P1[s])[0] - r[s] for s in range(cm.n_shapes)], axis=0)
            name = visual.geometryObjects[k].name
            assert d.max() <= COVER_TOL_M, f"{name}: a mesh point {d.max():.3f} m outside the shapes"
            checked, worst = checked + len(w), max(worst, d.max())
    assert checked > 100000 and worst < 0.025, (checked, worst)


def test_the_hand_shapes_keep_clear_of_the_grasp_point(g1, cm):
    """The hand's body shapes end short of the grasp point; only its tool sphere is there."""
    data = g1.forward(g1.half_sitting())
    P0, P1, r = cm.world_shapes(data)
    body = np.array([not n.endswith("_hand_tool") for n in cm.names])
    for side in ("right", "left"):
        G = data.oMf[g1.frame_id(g1.hand_frames[side])].translation
        d = point_segment_distance(G[None], P0, P1)[0] - r
        assert d[body].min() >= GRASP_CLEARANCE_M, cm.names[int(np.argmin(np.where(body, d, np.inf)))]


def test_the_hand_tool_spheres_are_the_plants_and_touch_the_environment_only(g1, cm):
    """Each grasp frame carries the physics plant's tool sphere (physics.yaml hand_sphere_radius_m),
    so the executor's dampers and the planner see what the plant's hand touches with; no
    self-collision pair names it (as Talos's palm and gripper)."""
    from humanoid_reach_ros.sim.physics.config import load_physics_config
    radius = load_physics_config(g1.spec.path.parent).hand_sphere_radius_m
    data = g1.forward(g1.half_sitting())
    P0, P1, r = cm.world_shapes(data)
    for side, tool in (("right", "r_hand_tool"), ("left", "l_hand_tool")):
        i = cm.names.index(tool)
        G = data.oMf[g1.frame_id(g1.hand_frames[side])].translation
        np.testing.assert_allclose([P0[i], P1[i]], [G, G], atol=1e-12)
        assert r[i] == pytest.approx(radius)
        assert i not in cm.pair_index


def test_every_moving_link_with_a_mesh_carries_a_shape_or_sits_inside_a_neighbours(g1, cm, visual):
    """Each shape-less link is a knuckle inside its neighbours' shapes (its mesh is checked
    above): the waist roll link and the ankle pitch links."""
    moving = {g1.model.names[o.parentJoint] for o in visual.geometryObjects}
    carried = {g1.model.names[g1.model.frames[g1.frame_id(l_)].parentJoint] for l_ in cm.links}
    bare = sorted(moving - carried)
    assert set(bare) == {g1.spec.chest_roll, g1.limbs["right_leg"].joints[4], g1.limbs["left_leg"].joints[4]}, bare
    assert moving == {*g1.joint_names, g1.model.names[1]}   # every joint moves a mesh, the free flyer the pelvis's


def test_half_sitting_is_free_of_self_collision_and_mirrored(g1, cm):
    P0, P1, r = cm.world_shapes(g1.forward(g1.half_sitting()))
    assert not cm.in_self_collision(P0, P1, r)
    d = cm.self_distances(P0, P1, r)
    assert d.min() > 0.015, cm.colliding_pairs(P0, P1, r, margin=0.015)
    # the model and its pairs are left-right mirror images
    names = set(cm.names)
    for n in names:
        if n[:2] in SWAP:
            assert SWAP[n[:2]] + n[2:] in names
    shapes = {s.name: s for s in cm.shapes}
    for s in cm.shapes:
        m = shapes[SWAP[s.name[:2]] + s.name[2:]] if s.name[:2] in SWAP else s
        assert m.radius == s.radius and m.kind == s.kind
        mirror = sorted([tuple(np.multiply(m.p0, [1, -1, 1])), tuple(np.multiply(m.p1, [1, -1, 1]))])
        assert np.allclose(sorted([s.p0, s.p1]), mirror), s.name
    pairs = {frozenset(p) for p in cm.pairs}
    for a, b in cm.pairs:
        m = frozenset(SWAP[x[:2]] + x[2:] if x[:2] in SWAP else x for x in (a, b))
        assert m in pairs, (a, b)


def test_the_zero_posture_touches_where_the_description_says(g1, cm):
    P0, P1, r = cm.world_shapes(g1.forward(g1.config(np.zeros(g1.n_joints))))
    hits = {frozenset(p[:2]) for p in cm.colliding_pairs(P0, P1, r)}
    assert hits == {frozenset(p) for p in (("r_upper_arm", "chest_lower"), ("l_upper_arm", "chest_lower"))}, hits


# ---------------------------------------------------------------- planning and looking (issue 23)
def test_every_limb_gets_the_numerical_solver_and_the_projector_goes_through_the_protocol(g1):
    """The G1's limbs have no closed form: all four get the numerical solver behind the limb
    protocol; the planner's projection has no fused leg kernel for them and goes through it."""
    from humanoid_reach_ros.planning.projector import Projector
    from humanoid_reach_ros.kinematics.registry import LimbIKSet

    ik = LimbIKSet(g1)
    assert {ik[n].kind for n in ik.names} == {"numerical"}
    proj = Projector(g1, ik)
    assert not proj.compiled
    q = proj.q_ref
    for arm in ("right", "left"):
        back = proj.project_plan_config(proj.plan_config_of(q[None], arm), arm)
        assert back.ok.all()
        np.testing.assert_allclose(back.q[0], q, atol=1e-7)


def test_the_g1_reaches_its_demo_valve_and_plans_the_way_home(g1):
    """The valve of the plant made for the G1's size (robot.yaml demo_scene), the map without
    the valve, as the demo's planner sees it: a collision-free reach ending at the valve, then
    the way home from the reached posture (the start-posture manifold checked through itself)."""
    from humanoid_reach_ros.nodes.common import scene_file_voxels
    from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
    from humanoid_reach_ros.planning.wgr import valve_region
    from humanoid_reach_ros.sim.scene import load_scene

    planner = ReachPlanner(g1, params=PlannerParams(safety_margin_m=0.01))
    planner.set_map(scene_file_voxels(g1.spec.demo_scene, planner.params.resolution_m, ("valve",)))
    target = load_scene(g1.spec.demo_scene).target.pose[:3, 3]
    out = planner.plan(g1.half_sitting_joints, PlanRequest(valve_region(target_p=target), seed=0,
                                                            time_budget_s=10.0))
    assert out.success, out.message
    assert planner.collision.check_batch(out.waypoints).all()
    np.testing.assert_allclose(g1.frame_pose(out.waypoints[-1], g1.hand_frames[out.arm]).translation, target,
                               atol=1e-6)
    for q in out.waypoints:   # the feet stay on their stance
        for s, stance in zip(g1.sole_frames, g1.stance_soles):
            np.testing.assert_allclose(g1.frame_pose(q, s).homogeneous, stance.homogeneous, atol=1e-6)
    home = planner.plan(out.waypoints[-1][N_BASE_Q:], PlanRequest(None, home=True, seed=0, time_budget_s=10.0))
    assert home.success, home.message
    np.testing.assert_allclose(home.waypoints[-1][N_BASE_Q:], g1.half_sitting_joints, atol=1e-6)


def test_a_look_without_a_neck_stops_short_of_the_map(g1):
    """The scan pattern on the G1 (directions, gazed at with the chest): in its demo scene the
    wide turns would swing a hand towards the passage pipe; those gazes stop where the body
    keeps ``security_distance_m + look_clearance_m`` (``held_back`` says so; the point is
    unseen unless the camera sees it from where the gaze stopped), the shortened motion keeps it
    (to 3 mm: it is checked at 20 samples of the way, and between two the body moves less than
    that here), and without a map every gaze goes all the way."""
    from humanoid_reach_ros.execution.requests import ExecutionRequests
    from humanoid_reach_ros.execution import config as reach_executor_params
    from humanoid_reach_ros.sim.scene import load_scene

    p = {k: spec.default for k, spec in reach_executor_params.PARAMETERS.items()}
    p["scene_file"] = ""
    free = ExecutionRequests(g1, p)
    req = ExecutionRequests(g1, p)
    req.scene_map(load_scene(g1.spec.demo_scene).voxelize(exclude_groups=("valve",)), "g1 plant")
    _, points = req.look_targets([], [])
    coll = req._look_collision()
    need = p["security_distance_m"] + p["look_clearance_m"]
    j, held = g1.half_sitting_joints, 0
    for k, point in enumerate(points):
        _, g = req.gaze(k, f"point {k}", point, j, "")
        _, g_free = free.gaze(k, f"point {k}", point, j, "")
        assert not g_free.held_back
        if g.held_back:
            held += 1
            assert g.held_back.startswith("turned ") and "of the map" in g.held_back
            assert g.visible or g.unseen_reason == f"not in view ({g.held_back})"
            d0 = coll.min_distance(g1.config(j, g1.base_on_feet(j)))
            for s in np.linspace(0.0, 1.0, 11):
                x = j + s * (g.joints - j)
                assert coll.min_distance(g1.config(x, g1.base_on_feet(x))) >= min(need, d0) - 0.003, (k, s)
        j = g.joints
    assert held >= 1
