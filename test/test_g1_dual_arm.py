"""The dual-arm whole-body reaching method (dual_arm/) on the third robot, the Unitree G1: no
limb has a closed form (kinematics/numerical_ik.py for all four), so the compiled lower body
runs the numerical tracking iteration inside its Newton on the waist (dual_arm/fast_legs.py)
and the control steps take the arms through NumericalLimbTracker; its own workspace file and
torso regression model (config/robots/g1/). A reach to two hand targets holds the exact
(whole-body) COG at its reference and every joint within its limits; reach_executor takes
``robot_config: g1`` for its dual-arm mode."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from action_msgs.msg import GoalStatus
from humanoid_reach_interfaces.action import ExecuteReach
from rclpy.action import ActionClient

from humanoid_reach_ros.dual_arm.balance import com_projection, polygon_margin, support_polygon, zmp_trajectory
from humanoid_reach_ros.dual_arm.controller import DualArmReachController
from humanoid_reach_ros.dual_arm.fast_legs import ClosedFormLowerBodyIK
from humanoid_reach_ros.dual_arm.lower_body_ik import LegTargets, LowerBodyIK
from humanoid_reach_ros.io import msgs
from humanoid_reach_ros.kinematics import IKReason, NumericalLimbTracker
from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel

MARGIN_M = 0.02
#: (right, left) hand targets [m] in the G1's workspace boxes, each reached by the method
#: (DualArmReachController.sample_reachable, seed 5)
PAIR = ((0.366, -0.048, 0.839), (0.244, 0.051, 0.732))


@pytest.fixture(scope="module")
def ctl():
    return DualArmReachController(RobotModel("g1"))


def test_the_g1_has_its_own_dual_arm_files_and_compiled_numerical_limbs(ctl):
    r = ctl.robot
    assert r.spec.dual_arm_workspace == str(config_path("robots/g1/dual_arm_workspace.yaml"))
    assert r.spec.torso_regression == str(config_path("robots/g1/torso_svr"))
    assert ctl.regression.meta["n_train"] >= 1000 and ctl.ws.com_offset_m == pytest.approx(0.06)
    assert isinstance(ctl.ik.lower, ClosedFormLowerBodyIK) and ctl.ik.lower.kind.tolist() == [1, 1]
    assert ctl.ik.arm_ik == {"right": None, "left": None}
    assert all(isinstance(ctl.ik.arm_track[s], NumericalLimbTracker) for s in ("right", "left"))
    drop = r.com(r.half_sitting())[2] - r.com(ctl.q_init)[2]
    assert drop == pytest.approx(ctl.ws.initial_com_drop_m, abs=1e-6)


def test_a_reach_to_two_hand_targets_holds_the_exact_cog_and_the_joint_limits(ctl):
    ctl.reset()
    r = ctl.robot
    t = ctl.ws.targets(np.array(PAIR[0]), np.array(PAIR[1]))
    plan = ctl.set_targets(t.p_right, t.R_right, t.p_left, t.R_left)
    assert plan.feasible, plan.reason
    steps = ctl.run()
    assert len(steps) == plan.n_steps > 100 and all(s.ok for s in steps), [s.reason for s in steps if not s.ok][:3]
    qs = np.array([s.q for s in steps])
    assert np.all(np.isfinite(qs))
    # both hands on their targets
    for side, p, R in (("right", t.p_right, t.R_right), ("left", t.p_left, t.R_left)):
        M = r.frame_pose(qs[-1], r.hand_frames[side])
        assert np.linalg.norm(M.translation - p) < 1e-9 and np.linalg.norm(pin.log3(M.rotation.T @ R)) < 1e-9
    # the exact COG (pinocchio's, whole body) at every step's reference: Algorithm 3 places it
    # with the previous step's arms, so the arms' own move of one step is the error; at rest, exact
    assert max(s.com_error for s in steps) < 1e-3
    assert np.linalg.norm(r.com(qs[-1]) - plan.com.p_com) < 1e-6
    # every joint within its limits, the support sole fixed, the swing sole at its stance pose
    assert all(r.in_limits(q[N_BASE_Q:], 1e-9) for q in qs)
    for q in qs[::25]:
        for sole, ref in zip((r.limbs["right_leg"].tip, r.limbs["left_leg"].tip), r.stance_soles):
            M = r.frame_pose(q, sole)
            assert np.linalg.norm(M.translation - ref.translation) < 1e-9
            assert np.abs(M.rotation - ref.rotation).max() < 1e-9
    # balanced: CoM projection and RNEA ZMP inside the soles' polygon, no joint faster than its limit
    traj = np.vstack([ctl.q_init[None], qs, qs[-1:]])
    poly = support_polygon(r)
    assert polygon_margin(poly, zmp_trajectory(r, traj, ctl.config.period_s)).min() >= MARGIN_M
    assert polygon_margin(poly, com_projection(r, traj)).min() >= MARGIN_M
    v = np.abs(np.diff(traj[:, N_BASE_Q:], axis=0)) / ctl.config.period_s
    assert np.all(v <= r.model.velocityLimit[6:] + 1e-9)


def test_the_compiled_numerical_legs_give_algorithm_3s_solution(ctl):
    """The compiled lower body (numerical legs + Newton on the waist) against Algorithm 3's
    iteration (LowerBodyIK): the same configuration to the LM tolerance, no fallback."""
    r = ctl.robot
    fast = ClosedFormLowerBodyIK(r, max_iter=100)
    ref = LowerBodyIK(r, max_iter=100)
    r_sole, l_sole = ctl.sole_support, ctl.sole_swing
    rng = np.random.default_rng(4)
    arms = [N_BASE_Q + i for s in ("right", "left") for i in r.limbs[f"{s}_arm"].joint_index]
    compared = 0
    for _ in range(12):
        q = ctl.q_init.copy()
        q[arms] += rng.uniform(-0.1, 0.1, len(arms))
        com = r.com(ctl.q_init) + rng.uniform([-0.01, -0.01, -0.03], [0.01, 0.01, 0.03])
        legs = LegTargets(com, ctl.R_torso, l_sole.translation, l_sole.rotation)
        a, b = ref.solve(q, legs, r_sole), fast.solve(q, legs, r_sole)
        if not a.converged:
            continue
        compared += 1
        assert b.converged and np.abs(pin.difference(r.model, a.q, b.q)).max() < 1e-5
        assert np.linalg.norm(r.com(b.q) - com) < 1e-7
    assert compared >= 10 and fast.fallbacks == 0


def test_the_numerical_arm_tracker_answers_bad_input_clearly(ctl):
    r = ctl.robot
    tracker = ctl.ik.arm_track["right"]
    q = ctl.q_init
    cols = [N_BASE_Q + i for i in r.limbs["right_arm"].joint_index]
    root = r.frame_pose(q, r.limbs["right_arm"].root)
    tip = r.frame_pose(q, r.hand_frames["right"])
    code, qa = tracker.solve(root.translation, root.rotation, tip.translation + [0.002, 0.0, 0.0], tip.rotation,
                             q[cols])
    assert code == IKReason.OK and np.abs(qa - q[cols]).max() < 0.05
    code, qa = tracker.solve(root.translation, root.rotation, tip.translation + [2.0, 0.0, 0.0], tip.rotation,
                             q[cols])
    assert code == IKReason.UNREACHABLE and np.all(np.isnan(qa))
    code, qa = tracker.solve(root.translation, root.rotation, [np.nan, 0.0, 0.0], tip.rotation, q[cols])
    assert code == IKReason.INVALID_INPUT and np.all(np.isnan(qa))
    with pytest.raises(ValueError, match=r"q_prev \(7,\)"):
        tracker.solve(root.translation, root.rotation, tip.translation, tip.rotation, q[cols][:6])
    with pytest.raises(ValueError, match="numerical kind"):
        NumericalLimbTracker(RobotModel("hrp2").limbs["right_arm"])


@pytest.mark.node
def test_reach_executor_takes_the_g1_for_its_dual_arm_mode(start_node, ros_probe, ctl) -> None:
    """reach_executor and joint_driver with ``robot_config: g1``: a MODE_DUAL_ARM goal to the
    pair above succeeds with both hands within 1 mm (the result's own measure)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from test_reach_executor_node import Run, status

    G = ExecuteReach.Goal
    diags = ros_probe.collect(DiagnosticArray, "/diagnostics")
    ex = start_node("reach_executor", params_file="config/reach_executor.yaml",
                    params={"robot_config": "g1", "scene_file": "", "diagnostics_period_s": 0.2,
                            "joint_states_timeout_s": 5.0, "joint_states_abort_s": 10.0},
                    ready_log=r"reach executor ready", timeout=180.0)   # warm-up: minutes on a loaded machine
    start_node("joint_driver", params_file="config/joint_driver.yaml",
               params={"robot_config": "g1", "command_timeout_s": 60.0}, ready_log=r"simulated g1")
    client = ActionClient(ros_probe.node, ExecuteReach, "/execute_reach")
    ros_probe.spin_until(client.server_is_ready, 20.0, "/execute_reach server", on_timeout=ex.log_tail)
    ros_probe.spin_until(lambda: (s := status(diags, ": inputs")) is not None and "current" in s.message, 20.0,
                         "executor to see /joint_states", on_timeout=ex.log_tail)
    t = ctl.ws.targets(np.array(PAIR[0]), np.array(PAIR[1]))
    goal = G(mode=G.MODE_DUAL_ARM, right_hand_target=msgs.pose_stamped(pin.SE3(t.R_right, t.p_right), "world"),
             left_hand_target=msgs.pose_stamped(pin.SE3(t.R_left, t.p_left), "world"))
    st, res = Run(ros_probe, client, goal).result(60.0)
    assert st == GoalStatus.STATUS_SUCCEEDED and res.success, res.message
    assert res.final_hand_error_m < 1e-3 and res.max_com_error_m < 2e-3 and res.steps > 100
    assert ex.alive()
