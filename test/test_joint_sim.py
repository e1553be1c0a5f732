"""Unit tests of humanoid_reach_ros.sim.joint_sim (no ROS graph)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.sim.joint_sim import JointSimulator

DT = 0.005


@pytest.fixture(scope="module")
def model() -> RobotModel:
    return RobotModel()


@pytest.fixture
def sim(model: RobotModel) -> JointSimulator:
    return JointSimulator(model, time_constant_s=0.01)


def test_starts_at_half_sitting_at_rest(sim: JointSimulator, model: RobotModel) -> None:
    np.testing.assert_allclose(sim.q, model.half_sitting_joints)
    np.testing.assert_array_equal(sim.dq, 0.0)
    np.testing.assert_allclose(sim.target, sim.q)
    assert sim.joint_names == model.joint_names and len(sim.q) == 30


@pytest.mark.parametrize(
    "names, positions, velocities, reason",
    [
        ([], [], None, "empty command"),
        (["RARM_JOINT0", "RARM_JOINT1"], [0.1], None, "2 joint names but 1 positions"),
        (["RARM_JOINT0"], [0.1, 0.2], None, "1 joint names but 2 positions"),
        (["RARM_JOINT0", "RARM_JOINT1"], [0.1, 0.2], [0.0], "2 joint names but 1 velocities"),
        (["RARM_JOINT0", "NOT_A_JOINT"], [0.1, 0.2], None, "unknown joint names: 'NOT_A_JOINT'"),
        (["RARM_JOINT0", "RARM_JOINT0"], [0.1, 0.2], None, "duplicate joint names: 'RARM_JOINT0'"),
        (["RARM_JOINT0", "RARM_JOINT1"], [0.1, math.nan], None, "non-finite positions: 'RARM_JOINT1=nan'"),
        (["RARM_JOINT0"], [math.inf], None, "non-finite positions: 'RARM_JOINT0=inf'"),
        (["RARM_JOINT0"], [-math.inf], None, "non-finite positions"),
        (["RARM_JOINT0"], [0.1], [math.nan], "non-finite velocities: 'RARM_JOINT0=nan'"),
    ],
)
def test_bad_commands_are_rejected_with_a_reason_and_the_last_good_one_is_held(
        sim: JointSimulator, names, positions, velocities, reason) -> None:
    good = sim.set_command(["RARM_JOINT0"], [-0.5], now=1.0)
    assert good.accepted and good.reason == ""
    target = sim.target.copy()
    result = sim.set_command(names, positions, velocities, now=2.0)
    assert not result.accepted
    assert reason in result.reason
    assert sim.last_rejection == result.reason
    assert sim.rejected_count == 1 and sim.accepted_count == 1
    np.testing.assert_array_equal(sim.target, target)
    assert sim.command_age(3.0) == pytest.approx(2.0)  # rejected commands do not refresh the age


def test_empty_velocity_array_means_position_only(sim: JointSimulator) -> None:
    assert sim.set_command(["HEAD_JOINT0"], [0.2], []).accepted
    assert sim.set_command(["HEAD_JOINT0"], [0.2], np.array([0.5])).accepted
    assert sim.commanded_velocity[sim.joint_names.index("HEAD_JOINT0")] == 0.5


def test_partial_command_updates_only_named_targets(sim: JointSimulator) -> None:
    before = sim.target.copy()
    assert sim.set_command(["RARM_JOINT0", "LLEG_JOINT3"], [-0.5, 1.0]).accepted
    changed = np.flatnonzero(sim.target != before)
    assert {sim.joint_names[i] for i in changed} == {"RARM_JOINT0", "LLEG_JOINT3"}
    assert sim.target[sim.joint_names.index("RARM_JOINT0")] == -0.5


def test_targets_beyond_limits_are_clipped_and_counted(sim: JointSimulator, model: RobotModel) -> None:
    i, k = model.joint_index["RARM_JOINT1"], model.joint_index["CHEST_JOINT1"]
    result = sim.set_command(["RARM_JOINT1", "CHEST_JOINT1", "RARM_JOINT0"], [5.0, -5.0, -0.5])
    assert result.accepted and result.clipped == ("RARM_JOINT1", "CHEST_JOINT1")
    assert sim.target[i] == model.upper[i] and sim.target[k] == model.lower[k]
    assert sim.clip_events == 1 and sim.clip_count[i] == 1 and sim.clip_count.sum() == 2
    for _ in range(400):
        sim.step(DT)
    assert sim.q[i] == pytest.approx(model.upper[i]) and sim.q[k] == pytest.approx(model.lower[k])
    assert model.in_limits(sim.q)


def test_unsaturated_step_is_exact_first_order(model: RobotModel) -> None:
    tau = 0.02
    sim = JointSimulator(model, time_constant_s=tau)
    j = model.joint_index["HEAD_JOINT0"]
    sim.set_command(["HEAD_JOINT0"], [sim.q[j] + 0.01])  # small: far from the velocity bound
    e0 = sim.target[j] - sim.q[j]
    sim.step(DT)
    assert sim.target[j] - sim.q[j] == pytest.approx(e0 * math.exp(-DT / tau), rel=1e-9)


def test_large_step_is_saturated_by_the_velocity_limit_and_never_overshoots(model: RobotModel) -> None:
    sim = JointSimulator(model, time_constant_s=0.01, velocity_scale=0.5)
    j = model.joint_index["RARM_JOINT0"]
    goal = -0.5
    sim.set_command(["RARM_JOINT0"], [goal])
    bound = 0.5 * model.velocity_limit[j]
    speeds, errors = [], []
    for _ in range(200):
        sim.step(DT)
        speeds.append(abs(sim.dq[j]))
        errors.append(sim.q[j] - goal)
    assert max(speeds) == pytest.approx(bound)        # saturated at s * vmax ...
    assert max(speeds) <= bound * (1 + 1e-12)          # ... and never beyond
    assert min(errors) >= 0.0                           # approached from above, never past the goal
    assert errors[-1] == pytest.approx(0.0, abs=1e-9)


def test_zero_time_constant_is_pure_rate_limit(model: RobotModel) -> None:
    sim = JointSimulator(model, time_constant_s=0.0)
    j = model.joint_index["HEAD_JOINT1"]
    start, goal = sim.q[j], 0.5
    sim.set_command(["HEAD_JOINT1"], [goal])
    steps = math.ceil((goal - start) / (model.velocity_limit[j] * DT))
    for _ in range(steps - 1):
        sim.step(DT)
    assert sim.q[j] < goal
    sim.step(DT)
    assert sim.q[j] == goal


@settings(max_examples=60, deadline=None)
@given(
    commands=st.lists(
        st.tuples(
            st.lists(st.integers(0, 29), min_size=1, max_size=30, unique=True),
            st.lists(st.floats(-6.0, 6.0), min_size=30, max_size=30),
            st.floats(1e-4, 0.05),
            st.integers(1, 20),
        ),
        min_size=1, max_size=8,
    ),
    tau=st.sampled_from([0.0, 0.005, 0.01, 0.1]),
    scale=st.sampled_from([0.1, 0.5, 1.0]),
)
def test_random_commands_never_exceed_position_or_velocity_limits(model, commands, tau, scale) -> None:
    sim = JointSimulator(model, time_constant_s=tau, velocity_scale=scale)
    bound = scale * model.velocity_limit
    for idx, values, dt, n_steps in commands:
        names = [model.joint_names[i] for i in idx]
        assert sim.set_command(names, [values[i] for i in idx]).accepted
        for _ in range(n_steps):
            q_prev = sim.q.copy()
            sim.step(dt)
            assert np.all(sim.q >= model.lower) and np.all(sim.q <= model.upper)
            assert np.all(np.abs(sim.dq) <= bound * (1 + 1e-9))
            np.testing.assert_allclose(sim.q - q_prev, sim.dq * dt, atol=1e-12)
            # monotone approach: each joint moves toward its target and stays on its side
            before, after = sim.target - q_prev, sim.target - sim.q
            assert np.all(before * after >= -1e-15) and np.all(np.abs(after) <= np.abs(before) + 1e-15)


def test_command_age_and_hold(sim: JointSimulator) -> None:
    assert sim.command_age(10.0) == math.inf
    sim.set_command(["RARM_JOINT0"], [-1.0], now=10.0)
    assert sim.command_age(10.25) == pytest.approx(0.25)
    for _ in range(10):
        sim.step(DT)
    sim.hold()
    np.testing.assert_array_equal(sim.target, sim.q)
    q = sim.q.copy()
    sim.step(DT)
    np.testing.assert_array_equal(sim.q, q)
    np.testing.assert_array_equal(sim.dq, 0.0)


def test_odometry_at_half_sitting_matches_the_stance(sim: JointSimulator, model: RobotModel) -> None:
    odom = sim.odometry()
    expected = model.base_on_feet(model.half_sitting_joints)
    assert odom.base.isApprox(expected, 1e-12)
    assert odom.left_foot_slip_m == pytest.approx(0.0, abs=1e-9)
    q = model.config(sim.q, odom.base)
    r_sole, l_sole = model.stance_soles
    assert model.frame_pose(q, "r_sole").isApprox(r_sole, 1e-9)
    assert model.frame_pose(q, "l_sole").isApprox(l_sole, 1e-9)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-0.3, 0.3), min_size=12, max_size=12))
def test_odometry_keeps_the_right_sole_fixed(model, offsets) -> None:
    sim = JointSimulator(model, time_constant_s=0.0)
    legs = model.limbs["right_leg"].joints + model.limbs["left_leg"].joints
    targets = [model.half_sitting_joints[model.joint_index[n]] + o for n, o in zip(legs, offsets)]
    sim.set_command(legs, targets)
    for _ in range(100):
        sim.step(DT)
    odom = sim.odometry()
    q = model.config(sim.q, odom.base)
    assert model.frame_pose(q, "r_sole").isApprox(model.stance_soles[0], 1e-9)
    left = model.frame_pose(q, "l_sole").translation
    assert odom.left_foot_slip_m == pytest.approx(np.linalg.norm(left - model.stance_soles[1].translation))


def test_moving_only_the_left_leg_keeps_the_base_and_reports_slip(sim: JointSimulator) -> None:
    base0 = sim.odometry().base
    sim.set_command(["LLEG_JOINT2"], [-0.2])
    for _ in range(200):
        sim.step(DT)
    odom = sim.odometry()
    assert odom.base.isApprox(base0, 1e-12)
    assert odom.left_foot_slip_m > 0.05


def test_odometry_result_is_a_copy(sim: JointSimulator) -> None:
    a = sim.odometry()
    a.base.translation = np.array([9.0, 9.0, 9.0])
    assert not sim.odometry().base.isApprox(a.base)


def test_invalid_construction_and_parameters(model: RobotModel) -> None:
    with pytest.raises(ValueError):
        JointSimulator(model, initial_joints=[0.0] * 29)
    with pytest.raises(ValueError):
        JointSimulator(model, initial_joints=[math.nan] * 30)
    sim = JointSimulator(model, initial_joints=[10.0] * 30)   # clipped into the limits
    assert model.in_limits(sim.q)
    with pytest.raises(ValueError):
        sim.velocity_scale = 0.0
    with pytest.raises(ValueError):
        sim.time_constant_s = -1.0


def test_a_late_command_is_caught_up_on_a_straight_line_keeping_the_feet(model: RobotModel) -> None:
    """Velocity limit coordinated over the joints: a command 40 ms ahead of the joints (a burst of
    late /joint_command messages) is caught up on the straight line toward it, every joint
    slowed together, so a balanced leg motion keeps the soles where they are (a per-joint clip
    moved the left sole 0.8 mm from the right, bench/session)."""
    sim = JointSimulator(model, time_constant_s=0.005, velocity_scale=1.0)
    q0 = sim.q.copy()
    rs, ls = model.sole_frames

    def left_in_right(q: np.ndarray) -> np.ndarray:
        c = model.config(q, model.base_on_feet(q))
        return model.frame_pose(c, rs).actInv(model.frame_pose(c, ls)).translation
    # the same crouch of both legs (the soles stay put), 40 ms of motion at the legs' limit at once
    legs = [i for i, n in enumerate(model.joint_names) if "LEG" in n]
    target = q0.copy()
    v = model.velocity_limit[legs]
    pattern = np.array([0.0, 0.0, -1.0, 2.0, -1.0, 0.0] * 2)   # hip, knee, ankle pitch: a crouch
    target[legs] += pattern * np.min(v) * 0.04
    assert np.linalg.norm(left_in_right(target) - left_in_right(q0)) < 1e-6
    sim.set_command(model.joint_names, target)
    drift, line = 0.0, 0.0
    for _ in range(40):
        sim.step(DT)
        drift = max(drift, float(np.linalg.norm(left_in_right(sim.q) - left_in_right(q0))))
        d = (sim.q - q0)[legs]
        u = pattern / np.linalg.norm(pattern)
        line = max(line, float(np.linalg.norm(d - (d @ u) * u)))
    assert line < 1e-12              # on the straight line toward the command
    assert drift < 1e-6, drift       # the soles kept where they were
    np.testing.assert_allclose(sim.q, target, atol=1e-9)


def _distance_to_polyline(p: np.ndarray, vertices: np.ndarray) -> float:
    best = np.inf
    for a, b in zip(vertices[:-1], vertices[1:]):
        ab = b - a
        t = 0.0 if not ab @ ab else float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(p - (a + t * ab))))
    return best


def test_a_burst_of_commands_is_played_along_its_own_path(model: RobotModel) -> None:
    """60 ms of commands on a curve arriving at once (a late delivery, a stalled driver loop)
    are played through one by one at the coordinated velocity limit, not cut across on the
    chord to the newest (whose sagitta moved one sole against the other by 0.13 mm in a
    bench/session run); then the newest is tracked as usual. Two at once (clock jitter) are not a
    burst."""
    sim = JointSimulator(model, time_constant_s=0.01, velocity_scale=1.0)
    q0 = sim.q.copy()
    i, j = model.joint_names.index("RARM_JOINT0"), model.joint_names.index("RARM_JOINT1")
    r = 0.08 * min(model.velocity_limit[i], model.velocity_limit[j])   # a quarter circle, 12 commands
    commands = []
    for th in np.linspace(0.0, np.pi / 2, 13)[1:]:
        c = q0.copy()
        c[i] += r * np.sin(th)
        c[j] += r * (1.0 - np.cos(th))
        commands.append(c)
    for c in commands:
        sim.set_command(model.joint_names, c)
    path = np.vstack([q0, *commands])
    worst = 0.0
    for _ in range(60):
        sim.step(DT)
        worst = max(worst, _distance_to_polyline(sim.q, path))
        assert np.all(np.abs(sim.dq) <= sim.velocity_bound + 1e-9)
    chord_sagitta = r * (1.0 - np.cos(np.pi / 4)) * np.sqrt(2.0)
    assert worst < 1e-12 < 0.1 * chord_sagitta, (worst, chord_sagitta)
    np.testing.assert_allclose(sim.q, commands[-1], atol=1e-9)

    # two commands between two steps: the newest is the target, the other is not visited
    sim2 = JointSimulator(model, time_constant_s=0.01, velocity_scale=1.0)
    sim2.set_command(model.joint_names, commands[0])
    sim2.set_command(model.joint_names, commands[1])
    sim3 = JointSimulator(model, time_constant_s=0.01, velocity_scale=1.0)
    sim3.set_command(model.joint_names, commands[1])
    np.testing.assert_array_equal(sim2.step(DT), sim3.step(DT))

    # a hold drops what was buffered
    sim.set_command(model.joint_names, q0)
    for c in commands:
        sim.set_command(model.joint_names, c)
    sim.hold()
    q_held = sim.q.copy()
    for _ in range(5):
        np.testing.assert_array_equal(sim.step(DT), q_held)
