"""The second humanoid, Talos (config/robots/talos, issue 13 part 5 groundwork): the description
loads from example-robot-data's URDF, the stance is level and symmetric, the legs get the
compiled closed form and the 7-DOF arms the redundant closed form behind the same protocol,
the collision model covers the meshes and half-sitting is free of self-collision and
balanced. And a small synthetic robot written in a test directory: nothing else in the
package is needed for a robot than its description."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml
from scipy.spatial.transform import Rotation

from humanoid_reach_ros.dual_arm.balance import polygon_margin, support_polygon
from humanoid_reach_ros.kinematics.general_limb import GeneralLimb
from humanoid_reach_ros.kinematics.hand_derived import LimbIK
from humanoid_reach_ros.kinematics.registry import LimbIKSet
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.shapes import load_collision_model, point_segment_distance
from humanoid_reach_ros.robot.spec import load_robot_spec, resolve_package_uri

ARMS = ("right_arm", "left_arm")
LEGS = ("right_leg", "left_leg")


@pytest.fixture(scope="module")
def talos():
    return RobotModel("talos")


@pytest.fixture(scope="module")
def ik(talos):
    return LimbIKSet(talos)


@pytest.fixture(scope="module")
def cm(talos):
    return load_collision_model(None, talos)


def _random_q(robot, rng):
    return robot.config(rng.uniform(robot.lower, robot.upper))


# ------------------------------------------------------------------ the description
def test_the_description_loads_from_the_packaged_urdf(talos):
    spec = talos.spec
    assert spec.urdf_path.name == "talos_reduced.urdf" and spec.urdf_path.is_file()
    assert "example-robot-data" in spec.urdf_path.parts and len(spec.package_dirs) == 1
    assert talos.n_joints == 32 and talos.model.nq == 39
    assert [len(talos.limbs[n].joints) for n in (*LEGS, *ARMS)] == [6, 6, 7, 7]
    # the grasp frames the description adds hang from the last arm joint, 0.20 m down the forearm axis
    for arm, frame in zip(ARMS, (talos.hand_frames["right"], talos.hand_frames["left"])):
        f = talos.model.frames[talos.frame_id(frame)]
        assert talos.model.names[f.parentJoint] == talos.limbs[arm].joints[-1]
        np.testing.assert_allclose(f.placement.translation, [0.0, 0.0, -0.20], atol=1e-12)
        np.testing.assert_allclose(f.placement.rotation, np.eye(3), atol=1e-12)
    # the chest joints by role: yaw about z, pitch about y; the head's pitch carries its yaw
    m = talos.model
    kind = {j: m.joints[m.getJointId(j)].shortname() for j in (*spec.chest_joints, *spec.head_joints)}
    assert [kind[spec.chest_yaw], kind[spec.chest_pitch], kind[spec.head_yaw], kind[spec.head_pitch]] == \
        ["JointModelRZ", "JointModelRY", "JointModelRZ", "JointModelRY"]


def test_robot_description_carries_the_added_frames(talos):
    """/robot_description (``description_xml``) has the description's grasp frames as fixed links:
    a model built from it alone puts them where RobotModel does (TF and RViz see them)."""
    assert set(talos.spec.frames) == {"gripper_right_grasp_frame", "gripper_left_grasp_frame"}
    model = pin.buildModelFromXML(talos.description_xml, pin.JointModelFreeFlyer())
    data = model.createData()
    q = talos.half_sitting()
    pin.framesForwardKinematics(model, data, q)
    for name in talos.spec.frames:
        assert name not in talos.urdf_xml and f'<link name="{name}"' in talos.description_xml
        np.testing.assert_allclose(data.oMf[model.getFrameId(name)].homogeneous,
                                   talos.frame_pose(q, name).homogeneous, atol=1e-12)
    assert RobotModel().description_xml == RobotModel().urdf_xml     # no added frames: the URDF as it is


def test_a_package_that_is_not_installed_is_named_with_its_pip_package(tmp_path):
    from humanoid_reach_ros.robot.spec import robot_config_path

    doc = yaml.safe_load(robot_config_path("talos").read_text())
    doc["urdf"] = "package://no-such-robot-data/robots/x.urdf"
    for key in ("dual_arm_workspace", "torso_regression"):   # named beside robot.yaml: Talos's own, by path
        doc[key] = str(robot_config_path("talos").parent / doc[key])
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match="pip install no-such-robot-data"):
        load_robot_spec(tmp_path / "robot.yaml")
    with pytest.raises(ValueError, match="no robots/talos_data/robots/nope.urdf in package 'example-robot-data'"):
        resolve_package_uri("package://example-robot-data/robots/talos_data/robots/nope.urdf")


def test_half_sitting_stance_is_level_symmetric_and_at_the_srdf_height(talos):
    q = talos.half_sitting()
    r, l_ = (talos.frame_pose(q, f) for f in talos.sole_frames)
    for s in (r, l_):
        np.testing.assert_allclose(s.rotation, np.eye(3), atol=1e-9)
        assert abs(s.translation[2]) < 1e-9
    np.testing.assert_allclose(r.translation * [1, -1, 1], l_.translation, atol=1e-9)
    assert r.translation[1] < 0 < l_.translation[1]
    # talos.srdf puts the root 1.01927 m above the floor in its half-sitting posture
    assert abs(q[2] - 1.01927) < 2e-5
    # the hands (grasp frames) mirror each other too
    hr, hl = (talos.frame_pose(q, talos.hand_frames[s]) for s in ("right", "left"))
    np.testing.assert_allclose(hr.translation * [1, -1, 1], hl.translation, atol=1e-6)


def test_the_camera_frame_is_an_optical_frame_looking_forward(talos):
    M = talos.frame_pose(talos.half_sitting(), talos.camera_frame)
    x, y, z = M.rotation.T   # its axes in the world: z forward, x right (-y world), y down
    assert z @ [1, 0, 0] > 0.99 and x @ [0, -1, 0] > 0.99 and y @ [0, 0, -1] > 0.99
    assert 1.5 < M.translation[2] < 1.7


def test_base_on_feet_keeps_the_right_sole_at_its_stance(talos):
    rng = np.random.default_rng(3)
    hs = talos.half_sitting_joints
    base = talos.base_on_feet(hs)   # half-sitting: the waist upright above the middle of the soles
    np.testing.assert_allclose(base.rotation, np.eye(3), atol=1e-9)
    assert abs(base.translation[1]) < 1e-9
    for _ in range(5):
        j = np.clip(hs + rng.normal(0, 0.2, talos.n_joints), talos.lower, talos.upper)
        q = talos.config(j, talos.base_on_feet(j))
        sole = talos.frame_pose(q, talos.sole_frames[0])
        np.testing.assert_allclose(sole.homogeneous, talos.stance_soles[0].homogeneous, atol=1e-9)


def test_half_sitting_cog_is_inside_the_support_polygon(talos):
    poly = support_polygon(talos)
    # both 0.205 x 0.122 plates, 0.17 m apart: the hull is 0.205 x 0.292
    np.testing.assert_allclose(np.ptp(poly, axis=0), [0.205, 0.17 + 0.122], atol=1e-9)
    margin = polygon_margin(poly, talos.com(talos.half_sitting())[:2])[0]
    assert margin > 0.05, margin


# ------------------------------------------------------------------ limb IK
@pytest.mark.parametrize("leg", LEGS)
def test_legs_get_the_compiled_closed_form_and_round_trip(talos, ik, leg):
    solver = ik[leg]
    assert isinstance(solver, LimbIK) and solver.kind == "leg" and solver.compiled
    rng = np.random.default_rng(5)
    q = rng.uniform(solver.lower, solver.upper, size=(3000, 6))
    root_p, root_R = np.array([0.02, -0.03, 1.0]), Rotation.from_euler("xyz", [0.05, 0.2, -0.1]).as_matrix()
    p, R = solver.fk(root_p, root_R, q)
    res = ik.solve(leg, root_p, root_R, p, R)
    assert res.ok.all(), res.failure_counts()
    p2, R2 = solver.fk(root_p, root_R, res.q)
    assert np.abs(p2 - p).max() < 1e-9 and np.abs(R2 - R).max() < 1e-9
    # the compiled kernel agrees with the numpy reference
    ref = solver.solve_reference(root_p, root_R, p[:300], R[:300])
    np.testing.assert_allclose(res.q[:300], ref.q, atol=1e-12)
    # the limb's FK is pinocchio's (world, whole model)
    for k in range(5):
        j = talos.half_sitting_joints.copy()
        j[list(talos.limbs[leg].joint_index)] = q[k]
        full = talos.config(j)
        base = talos.frame_pose(full, talos.limbs[leg].root)
        pk, Rk = solver.fk(base.translation, base.rotation, q[k])
        sole = talos.frame_pose(full, talos.limbs[leg].tip)
        np.testing.assert_allclose(pk[0], sole.translation, atol=1e-12)
        np.testing.assert_allclose(Rk[0], sole.rotation, atol=1e-12)


@pytest.mark.parametrize("arm", ARMS)
def test_seven_dof_arms_get_the_redundant_closed_form_and_round_trip(talos, ik, arm):
    solver = ik[arm]
    assert isinstance(solver, GeneralLimb) and solver.kind == "redundant" and solver.n_joints == 7
    rng = np.random.default_rng(6)
    q = rng.uniform(solver.lower, solver.upper, size=(400, 7))
    root_p, root_R = np.array([0.0, 0.0, 1.1]), Rotation.from_euler("z", 0.3).as_matrix()
    p, R = solver.fk(root_p, root_R, q)
    # with the drawn joints as reference, the drawn solution itself comes back (its first joint is tried first)
    exact = ik.solve(arm, root_p, root_R, p, R, q_ref=q)
    assert exact.ok.all() and exact.q.shape == (400, 7)
    np.testing.assert_allclose(exact.q, q, atol=1e-6)
    # from the default reference, the grid of the first joint (16 values) reaches most poses
    res = ik.solve(arm, root_p, root_R, p, R)
    assert res.ok.mean() > 0.9, res.ok.mean()
    p2, R2 = solver.fk(root_p, root_R, res.q[res.ok])
    assert np.abs(p2 - p[res.ok]).max() < 1e-9 and np.abs(R2 - R[res.ok]).max() < 1e-9
    assert np.all((res.q[res.ok] >= solver.lower - 1e-12) & (res.q[res.ok] <= solver.upper + 1e-12))
    # reach bounds: every reachable pose passes the prefilter, poses 1 m beyond it fail both
    assert solver.maybe_reachable(root_p, root_R, p, R).all()
    far = p + (p - root_p) / np.linalg.norm(p - root_p, axis=1, keepdims=True)
    assert not solver.maybe_reachable(root_p, root_R, far, R).any()
    assert not ik.solve(arm, root_p, root_R, far, R).ok.any()
    # the limb's FK is pinocchio's
    j = talos.half_sitting_joints.copy()
    j[list(talos.limbs[arm].joint_index)] = q[0]
    full = talos.config(j)
    chest = talos.frame_pose(full, talos.limbs[arm].root)
    hand = talos.frame_pose(full, talos.limbs[arm].tip)
    pk, Rk = solver.fk(chest.translation, chest.rotation, q[0])
    np.testing.assert_allclose(pk[0], hand.translation, atol=1e-12)
    np.testing.assert_allclose(Rk[0], hand.rotation, atol=1e-12)


@pytest.mark.parametrize("arm", ARMS)
def test_the_reach_centres_of_a_seven_dof_arm_hold_every_posture(talos, ik, arm):
    """GeneralLimb.reach_centres (the out-of-reach proof's tight form): at any joint angles, the
    joint-2 centre is within the slack of a point on the joint-1 circle and the wrist centre
    within the reach of it -- and the reach is the subchain's, well under l1 + l2."""
    solver = ik[arm]
    pts, slack, reach = solver.reach_centres(0.05)
    rng = np.random.default_rng(8)
    q = rng.uniform(solver.lower, solver.upper, size=(5000, 7))
    q[:2500, 3] = solver.upper[3]                   # elbow straight: the reach is attained
    j = talos.half_sitting_joints.copy()
    names = talos.limbs[arm].joints
    centre, wrist = [], []
    for row in q[::10]:
        j[list(talos.limbs[arm].joint_index)] = row
        full = talos.config(j)
        chest = talos.frame_pose(full, talos.limbs[arm].root)
        to_chest = lambda p, chest=chest: chest.rotation.T @ (p - chest.translation)   # noqa: E731
        centre.append(to_chest(talos.frame_pose(full, names[1].replace("_joint", "_link")).translation))
        wrist.append(to_chest(talos.frame_pose(full, names[4].replace("_joint", "_link")).translation))
    centre, wrist = np.array(centre), np.array(wrist)
    assert np.min(np.linalg.norm(centre[:, None] - pts[None], axis=2), axis=1).max() <= slack + 1e-12
    d = np.linalg.norm(wrist - centre, axis=1)
    assert d.max() <= reach + 1e-9 and d.max() > reach - 1e-3
    assert reach < solver.l1 + solver.l2 - 0.1


def test_half_sitting_hands_come_back_through_the_arm_ik(talos, ik):
    q = talos.half_sitting()
    for arm, side in zip(ARMS, ("right", "left")):
        chest = talos.frame_pose(q, talos.limbs[arm].root)
        hand = talos.frame_pose(q, talos.hand_frames[side])
        res = ik.solve(arm, chest.translation, chest.rotation, hand.translation, hand.rotation)
        assert res.ok.all()
        np.testing.assert_allclose(res.q[0], talos.half_sitting_joints[list(talos.limbs[arm].joint_index)],
                                   atol=1e-9)


# ------------------------------------------------------------------ collision model
#: a mesh point may be this far outside the shapes (the waist and chest box corners: 0.033 m)
COVER_TOL_M = 0.035
#: the hand shapes end this far short of the grasp point: the fingers beyond are not covered
GRASP_CLEARANCE_M = 0.03


def _mesh_points(robot):
    """(geometry object, joint it moves with, vertices in that object's frame) of the URDF's
    collision meshes (coal applied the URDF's scale)."""
    geom = pin.buildGeomFromUrdfString(robot.model, robot.urdf_xml, pin.GeometryType.COLLISION,
                                       package_dirs=[str(d) for d in robot.spec.package_dirs])
    out = []
    for k, obj in enumerate(geom.geometryObjects):
        g = obj.geometry
        if callable(getattr(g, "vertices", None)):
            v = np.asarray(g.vertices())
        elif hasattr(g, "halfSide"):
            v = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float) * np.asarray(g.halfSide)
        else:
            continue
        out.append((k, obj.parentJoint, v))
    return geom, out


def test_the_collision_model_covers_the_meshes(talos, cm):
    geom, meshes = _mesh_points(talos)
    gdata = pin.GeometryData(geom)
    hand_joints = {talos.model.getJointId(j) for j in (talos.limbs["right_arm"].joints[-1],
                                                       talos.limbs["left_arm"].joints[-1], *talos.spec.gripper_joints)}
    grasp = {talos.model.frames[talos.frame_id(f)].parentJoint: talos.frame_id(f) for f in talos.hand_frames.values()}
    rng = np.random.default_rng(8)
    postures = ([talos.half_sitting(), talos.config(np.zeros(talos.n_joints))]
                + [_random_q(talos, rng) for _ in range(3)])
    checked = 0
    for q in postures:
        data = talos.forward(q)
        pin.updateGeometryPlacements(talos.model, data, geom, gdata, q)
        P0, P1, r = cm.world_shapes(data)
        for k, joint, v in meshes:
            M = gdata.oMg[k]
            w = v @ M.rotation.T + M.translation
            if joint in hand_joints:   # the fingers: points less than the clearance above the grasp point
                arm_joint = joint if joint in grasp else talos.model.parents[joint]
                G = data.oMf[grasp[arm_joint]]
                w = w[(w - G.translation) @ G.rotation[:, 2] >= GRASP_CLEARANCE_M]
                if not len(w):
                    continue
            d = np.min([point_segment_distance(w, P0[s], P1[s])[0] - r[s] for s in range(cm.n_shapes)], axis=0)
            name = geom.geometryObjects[k].name
            assert d.max() <= COVER_TOL_M, f"{name}: a mesh point {d.max():.3f} m outside the shapes"
            checked += len(w)
    assert checked > 20000


def test_every_moving_link_with_a_mesh_carries_a_shape_or_sits_inside_a_neighbours(talos, cm):
    """Each shape-less link is a knuckle inside its neighbours' shapes (its mesh is checked
    above): the wrist roll (the sixth arm joint's link) only."""
    geom, _ = _mesh_points(talos)
    moving = {talos.model.names[o.parentJoint] for o in geom.geometryObjects}
    carried = {talos.model.names[talos.model.frames[talos.frame_id(l_)].parentJoint] for l_ in cm.links}
    bare = sorted(moving - carried)
    assert set(bare) == {talos.limbs["right_arm"].joints[5], talos.limbs["left_arm"].joints[5]}, bare


def test_half_sitting_is_free_of_self_collision_and_mirrored(talos, cm):
    P0, P1, r = cm.world_shapes(talos.forward(talos.half_sitting()))
    assert not cm.in_self_collision(P0, P1, r)
    d = cm.self_distances(P0, P1, r)
    assert d.min() > 0.008, cm.colliding_pairs(P0, P1, r, margin=0.008)
    # the model and its pairs are left-right mirror images
    names = set(cm.names)
    swap = {"r_": "l_", "l_": "r_"}
    for n in names:
        if n[:2] in swap:
            assert swap[n[:2]] + n[2:] in names
    pairs = {frozenset(p) for p in cm.pairs}
    for a, b in cm.pairs:
        m = frozenset(swap.get(x[:2], x[:2]) + x[2:] if x[:2] in swap else x for x in (a, b))
        assert m in pairs, (a, b)


def test_the_zero_posture_touches_where_the_description_says(talos, cm):
    P0, P1, r = cm.world_shapes(talos.forward(talos.config(np.zeros(talos.n_joints))))
    hits = {frozenset(p[:2]) for p in cm.colliding_pairs(P0, P1, r)}
    assert hits == {frozenset(p) for p in (("r_forearm", "waist_front"), ("l_forearm", "waist_front"),
                                           ("r_hand", "r_thigh_outer"), ("l_hand", "l_thigh_outer"))}, hits


# ------------------------------------------------------------------ planning with 7-DOF arms
@pytest.fixture(scope="module")
def planner(talos):
    from humanoid_reach_ros.planning.reach import ReachPlanner

    return ReachPlanner(talos)


def test_the_planning_space_of_a_seven_joint_arm_has_eleven_columns(talos, planner):
    proj = planner.projector
    assert proj.arm_dof == {"right": 7, "left": 7} and proj.plan_dim("right") == 11
    q = talos.half_sitting()
    for arm in ("right", "left"):
        q_plan = proj.plan_config_of(q, arm)
        assert q_plan.shape == (1, 11)
        back = proj.project_plan_config(q_plan, arm)
        assert back.ok.all()
        np.testing.assert_allclose(back.q[0], q, atol=1e-9)
    with pytest.raises(ValueError, match="11 columns"):
        proj.project_plan_config(np.zeros((1, 10)), "right")
    assert len(planner.planning_space("right").lower) == 11


@pytest.mark.parametrize("target, arm", [((0.55, -0.25, 1.0), "right"), ((0.5, 0.3, 0.5), "left")])
def test_talos_plans_a_reach_in_free_space(talos, planner, target, arm):
    from humanoid_reach_ros.planning.reach import PlanRequest
    from humanoid_reach_ros.planning.wgr import valve_region

    planner.set_map(np.zeros((0, 3)))
    region = valve_region(target_p=target)
    out = planner.plan(talos.half_sitting_joints, PlanRequest(region, arm=arm, seed=0, time_budget_s=10.0))
    assert out.success, out.message
    assert out.arm == arm and out.waypoints_plan.shape[1] == 11
    hand = talos.frame_pose(out.waypoints[-1], talos.hand_frames[arm])
    np.testing.assert_allclose(hand.translation, region.target_p, atol=1e-6)
    for q in out.waypoints:
        for s, stance in zip(talos.sole_frames, talos.stance_soles):
            np.testing.assert_allclose(talos.frame_pose(q, s).homogeneous, stance.homogeneous, atol=1e-6)


def test_talos_reaches_the_plant_valve(talos, planner):
    from humanoid_reach_ros.planning.reach import PlanRequest
    from humanoid_reach_ros.planning.wgr import valve_region

    from humanoid_reach_ros.nodes.common import scene_file_voxels
    from humanoid_reach_ros.paths import config_path

    planner.set_map(scene_file_voxels(config_path("scenes/plant.yaml"), planner.params.resolution_m, ("valve",)))
    out = planner.plan(talos.half_sitting_joints, PlanRequest(valve_region(), seed=0, time_budget_s=10.0))
    assert out.success, out.message
    check = planner.collision
    assert check.check_batch(out.waypoints).all()
    hand = talos.frame_pose(out.waypoints[-1], talos.hand_frames[out.arm])
    np.testing.assert_allclose(hand.translation, valve_region().target_p, atol=1e-6)


def test_the_whole_body_executor_runs_a_talos_reach_unchanged(talos, cm):
    """The executor is whole-body on pinocchio: a planned plant reach of the 7-DOF arm runs to the
    end with feet, COG, distances and the hand as for HRP-2 (test_executor.py's criteria)."""
    from humanoid_reach_ros.control.executor import ExecutorParams, WholeBodyExecutor
    from humanoid_reach_ros.geometry.sphere_tree import SphereTree
    from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
    from humanoid_reach_ros.planning.wgr import valve_region
    from humanoid_reach_ros.sim.scene import load_scene

    scene = load_scene("scenes/plant.yaml")
    voxels = scene.voxelize(0.02, exclude_groups=("valve",))
    planner = ReachPlanner(talos, PlannerParams(time_budget_s=5.0))
    planner.set_map(voxels)
    out = planner.plan(talos.half_sitting_joints, PlanRequest(valve_region(scene.target.pose), arm="right", seed=3))
    assert out.success, out.message
    ref = out.trajectory
    ex = WholeBodyExecutor(talos, cm, ExecutorParams())
    ex.set_environment(SphereTree.from_voxels(voxels, 0.02))
    j0 = ref.position(0.0)
    q0 = talos.config(j0, talos.base_on_feet(j0))
    soles0 = [talos.frame_pose(q0, f).translation for f in talos.sole_frames]
    ex.start(q0, ref, "right")
    results = [ex.step() for _ in range(int(np.ceil(ref.duration / 0.005)) + 60)]
    m = [r.metrics for r in results]
    assert min(x.min_distance_m for x in m) >= ExecutorParams().security_distance_m - 2e-3
    assert min(x.self_distance_m for x in m) >= 0.0
    assert max(x.com_error_m for x in m) < 1e-3
    for r in results[::25] + [results[-1]]:
        for f, s0 in zip(talos.sole_frames, soles0):
            assert np.linalg.norm(talos.frame_pose(r.q, f).translation - s0) < 1e-4
    assert results[-1].done and m[-1].hand_error_m < 1e-3 and m[-1].progress == 1.0


# ------------------------------------------------------------------ a start off the planning manifold
# Where the executor left Talos after a left-arm reach to the valve (`make demo ROBOT=talos --no-scan`):
# the waist turned 20 deg; the trunk placed by COG_approx with the other limbs at the reference leaves
# the right foot out of the leg's reach, so the start did not project and the way home failed for both
# arms (START_IN_COLLISION: "start_projection").
AFTER_LEFT_REACH = [0.3504, -0.0939, -0.5588, 0.899, -0.4187, 0.0578, 0.3491, -0.1108, -0.632, 0.8563, -0.3028,
                    0.0748, -0.1194, 0.0933, -1.1942, 1.5028, -0.8776, -0.935, -1.232, -0.767, -0.5478, 0.0, -0.295,
                    -0.1979, -0.0048, -0.5062, 0.0001, -0.0017, 0.1032, 0.0, -0.0042, 0.0001]


def test_a_start_off_the_manifold_still_goes_home(talos):
    from humanoid_reach_ros.planning.reach import PlannerParams, PlanRequest, ReachPlanner
    planner = ReachPlanner(talos, params=PlannerParams(time_budget_s=3.0))
    planner.set_map(np.empty((0, 3)))
    j = np.array(AFTER_LEFT_REACH)
    proj, q = planner.projector, planner.start_config(j)
    for arm in ("left", "right"):   # as it is, the start does not project (what failed)
        assert not proj.project_plan_config(proj.plan_config_of(q, arm), arm).ok[0]
    q_proj, start_plan = planner._projected_start(q, "left")
    assert q_proj is not None
    assert np.allclose(start_plan[:7], proj.plan_config_of(q, "left")[0][:7])   # the arm's joints kept
    out = planner.plan(j, PlanRequest(None, arm="auto", home=True, seed=0))
    assert out.success, out.message
    assert np.allclose(out.positions[0], j, atol=1e-3)   # (rounded above: one joint 4e-5 rad past its limit)
    assert np.max(np.abs(out.positions[-1] - talos.half_sitting_joints)) < 1e-6
