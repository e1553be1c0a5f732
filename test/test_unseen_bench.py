"""bench/unseen.py without a graph: the truth check (capsules vs a scene file's primitives by
exact signed distance, ``testing/truth.py``) and the summary of recorded targets."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from humanoid_reach_ros.codes import ErrorCode
from humanoid_reach_ros.sim.scene import Box, Cylinder, Plane, Sphere, Torus
from humanoid_reach_ros.testing.truth import (
    TrajectoryAudit, capsule_signed_distance, sample_times, segment_min_sdf, shapes_vs_primitives)

BENCH = Path(__file__).resolve().parents[1] / "bench"
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import unseen  # noqa: E402

R = 0.05     # capsule radius of the checks


def capsule_along_x(y: float, z: float = 0.0, half: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    return np.array([[-half, y, z]]), np.array([[half, y, z]])


# ---------------------------------------------------------------- the truth check
def test_a_capsule_through_a_box_penetrates_and_one_1cm_beside_does_not():
    cube = Box(name="cube", center=(0.0, 0.0, 0.0), size=(0.2, 0.2, 0.2))
    assert capsule_signed_distance(cube, *capsule_along_x(0.0), R)[0] == pytest.approx(-0.15, abs=1e-7)
    assert capsule_signed_distance(cube, *capsule_along_x(0.1 + R + 0.01), R)[0] == pytest.approx(0.01, abs=1e-7)
    assert capsule_signed_distance(cube, *capsule_along_x(0.1 + R - 0.002), R)[0] == pytest.approx(-0.002, abs=1e-7)
    # rotated about z: through its centre 10 cm deep (+ the radius); 1 cm beyond its farthest corner in y
    box = Box(name="box", center=(0.0, 0.0, 0.0), size=(0.2, 0.2, 0.2), rpy=(0.0, 0.0, 0.3))
    assert capsule_signed_distance(box, *capsule_along_x(0.0), R)[0] == pytest.approx(-0.15, abs=1e-7)
    corner_y = box.bounds()[1][1]
    assert capsule_signed_distance(box, *capsule_along_x(corner_y + R + 0.01), R)[0] == pytest.approx(0.01, abs=1e-7)


def test_a_capsule_through_a_cylinder_penetrates_and_one_1cm_beside_does_not():
    pipe = Cylinder(name="pipe", p0=(0.0, 0.0, -1.0), p1=(0.0, 0.0, 1.0), radius=0.1)
    assert capsule_signed_distance(pipe, *capsule_along_x(0.0), R)[0] == pytest.approx(-0.15, abs=1e-7)
    assert capsule_signed_distance(pipe, *capsule_along_x(0.1 + R + 0.01), R)[0] == pytest.approx(0.01, abs=1e-7)
    # grazing: 2 mm inside
    assert capsule_signed_distance(pipe, *capsule_along_x(0.1 + R - 0.002), R)[0] == pytest.approx(-0.002, abs=1e-7)
    # a capsule beyond the flat cap: clearance to the cap
    P0, P1 = np.array([[-0.5, 0.0, 1.0 + R + 0.01]]), np.array([[0.5, 0.0, 1.0 + R + 0.01]])
    assert capsule_signed_distance(pipe, P0, P1, R)[0] == pytest.approx(0.01, abs=1e-7)


def test_sphere_plane_and_torus_distances_are_exact():
    ball = Sphere(name="ball", center=(0.3, 0.2, 0.0), radius=0.1)
    assert capsule_signed_distance(ball, *capsule_along_x(0.0), R)[0] == pytest.approx(0.2 - 0.1 - R, abs=1e-7)
    wall = Plane(name="wall", normal=(0.0, 0.0, 1.0), offset=-0.3)     # solid below z = -0.3
    P0, P1 = np.array([[0.0, 0.0, -0.2]]), np.array([[0.0, 0.0, 0.4]])
    assert capsule_signed_distance(wall, P0, P1, R)[0] == pytest.approx(0.1 - R, abs=1e-7)
    rim = Torus(name="rim", center=(0.0, 0.0, 0.0), axis=(1.0, 0.0, 0.0), major_radius=0.2, minor_radius=0.02)
    # through the tube (its axis crosses y = 0.2) and through the hole
    assert capsule_signed_distance(rim, *capsule_along_x(0.2), 0.01)[0] == pytest.approx(-0.03, abs=1e-7)
    assert capsule_signed_distance(rim, *capsule_along_x(0.0), 0.01)[0] == pytest.approx(0.17, abs=1e-7)
    # a segment whose nearest point to the torus is not one of 16 even samples
    d, u = segment_min_sdf(rim, np.array([[0.013, 0.2, -1.0]]), np.array([[0.013, 0.2, 1.0]]))
    assert d[0] == pytest.approx(0.013 - 0.02, abs=1e-7)    # passes 13 mm off the tube's axis, at z = 0
    assert u[0] == pytest.approx(0.5, abs=1e-3)      # the distance is flat (quadratic) about its minimum


def test_bad_segments_are_refused():
    ball = Sphere(name="ball", center=(0.0, 0.0, 0.0), radius=0.1)
    with pytest.raises(ValueError, match="both be"):
        segment_min_sdf(ball, np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        segment_min_sdf(ball, np.full((1, 3), np.nan), np.zeros((1, 3)))
    assert segment_min_sdf(ball, np.zeros((0, 3)), np.zeros((0, 3)))[0].shape == (0,)


def test_shapes_vs_primitives_names_the_nearest_and_skips_the_far():
    prims = [Box(name="near", center=(0.0, 0.3, 0.0), size=(0.1, 0.1, 0.1)),
             Sphere(name="far", center=(5.0, 5.0, 5.0), radius=0.1)]
    P0, P1 = capsule_along_x(0.0)
    d, which = shapes_vs_primitives(prims, np.vstack([P0, P0 + [0, 10, 0]]), np.vstack([P1, P1 + [0, 10, 0]]),
                                    np.array([R, R]), near_m=0.5)
    assert which[0] == 0 and d[0] == pytest.approx(0.25 - R, abs=1e-7)
    assert which[1] == -1 and d[1] == 0.5


def test_sample_times_put_substeps_between_samples():
    t = sample_times(np.array([0.0, 1.0, 3.0]), np.array([3, 1]))
    assert np.allclose(t, [0.0, 0.25, 0.5, 0.75, 1.0, 2.0, 3.0])


@pytest.fixture(scope="module")
def robot_audit():
    from humanoid_reach_ros.robot.model import RobotModel
    from humanoid_reach_ros.robot.shapes import load_collision_model
    robot = RobotModel()
    return robot, load_collision_model(None, robot)


def test_a_trajectory_through_a_hidden_post_is_caught_between_its_samples(robot_audit):
    """Two samples, the right arm swinging forward between them: a small post stands halfway along
    the hand's sweep, so only the points evaluated between the samples can find it."""
    robot, cm = robot_audit
    j0 = robot.half_sitting_joints.copy()
    hand = cm.index("r_hand")                            # HRP-2's collision model (the default robot)
    shoulder = robot.limbs["right_arm"].joint_index[0]   # shoulder pitch
    j1 = j0.copy()
    j1[shoulder] = j0[shoulder] - 1.2
    P0, P1, _ = unseen.body_capsules(robot, cm, j0)
    Q0, Q1, _ = unseen.body_capsules(robot, cm, j1)
    a, b = P1[hand], Q1[hand]
    assert np.linalg.norm(a - b) > 0.3          # the hand's end sweeps far between the two samples
    mid = 0.5 * (a + b)
    post = Sphere(name="post", center=tuple(mid), radius=0.01)
    coarse = TrajectoryAudit(robot, cm, [post], substeps=0, step_m=10.0)
    fine = TrajectoryAudit(robot, cm, [post])
    times, Q = np.array([0.0, 1.0]), np.vstack([j0, j1])
    assert not coarse.check(times, Q)[0].penetrating         # the samples alone miss it
    contact, n = fine.check(times, Q)
    assert contact.penetrating and contact.primitive == "post" and n > 10
    assert 0.0 < contact.time_s < 1.0
    assert fine.clearance(j0).distance_m > 0.0 and fine.clearance(j1).distance_m > 0.0


# ---------------------------------------------------------------- the summary
def record(index: int, final: int | None, *, check=None, truth=None, looks: int = 0, **extra) -> dict:
    r = {"scene": "s", "seed": 1, "index": index, "target": [0.1 * index, 0.0, 1.0], "sector": "behind",
         "plan_seed": 1000 + index, "looks": looks, "looks_ok": True, "final_code": final,
         "codes": [] if final is None else [final]}
    if check is not None:
        r["check"] = check
    if truth is not None:
        r["truth"] = truth
    r.update(extra)
    return r


CLEAR = {"penetrating": False, "distance_mm": 12.0, "primitive": "p", "hidden": False, "shape": "r_hand",
         "time_s": 1.0, "configurations": 100}
INSIDE = {"penetrating": True, "distance_mm": -7.5, "primitive": "hidden_0", "hidden": True, "shape": "l_forearm",
          "time_s": 0.8, "configurations": 100}
FO = {"feasible_observable": True, "code": "SUCCESS"}
NOT_OBSERVABLE = {"feasible_observable": False, "code": "UNOBSERVED_SPACE"}
INFEASIBLE = {"feasible_observable": False, "code": "NO_GOAL_FOUND"}


def test_summary_counts_every_target_and_names_the_worst_penetration():
    recs = [record(0, ErrorCode.SUCCESS, check=CLEAR, truth=FO),
            record(1, ErrorCode.SUCCESS, check=INSIDE, truth=FO),           # reached through an obstacle: missed
            record(2, ErrorCode.UNOBSERVABLE_SPACE, truth=NOT_OBSERVABLE),
            record(3, ErrorCode.UNOBSERVED_SPACE, truth=FO, looks=3),        # looked 3 times, still unobserved
            record(4, ErrorCode.TARGET_OUT_OF_REACH, truth=INFEASIBLE,      # an earlier look left it in a box
                   start_check={"penetrating": True, "distance_mm": -3.0, "primitive": "hidden_2", "shape": "l_thigh"})]
    s = unseen.summarize(recs)
    assert s["starts_inside_true_obstacles"] == 1 and s["starts_inside"][0]["depth_mm"] == 3.0
    assert s["targets"] == 5 and s["unseen_plans"] == 2
    assert s["plans_penetrating_true_obstacles"] == 1 and s["penetrating_through_hidden"] == 1
    assert s["worst_penetration_mm"] == pytest.approx(7.5)
    w = s["worst_penetration"]
    assert (w["index"], w["primitive"], w["shape"], w["target"]) == (1, "hidden_0", "l_forearm", [0.1, 0.0, 1.0])
    assert s["unobservable_answers"] == 1 and s["unobserved_answers"] == 1
    assert s["feasible_observable_targets"] == 3 and s["feasible_observable_reached"] == 1
    assert s["feasible_observable_success_rate"] == pytest.approx(1 / 3, abs=1e-4)
    assert s["codes"] == {"SUCCESS": 2, "UNOBSERVABLE_SPACE": 1, "UNOBSERVED_SPACE": 1, "TARGET_OUT_OF_REACH": 1}
    assert s["penetrating_in_stance_zone"] == 0 and s["plans_penetrating_beyond_stance_zone"] == 1


def test_a_penetration_of_an_obstacle_inside_the_stance_zone_is_counted_apart_but_still_counted():
    in_zone = dict(INSIDE, in_stance_zone=True)
    s = unseen.summarize([record(0, ErrorCode.SUCCESS, check=in_zone, truth=FO),
                          record(1, ErrorCode.SUCCESS, check=INSIDE, truth=FO)])
    assert s["plans_penetrating_true_obstacles"] == 2
    assert s["penetrating_in_stance_zone"] == 1 and s["plans_penetrating_beyond_stance_zone"] == 1
    assert [c["in_stance_zone"] for c in s["penetrating_cases"]] == [True, None]


def test_a_missing_measurement_or_a_failed_step_is_a_missed_target_never_skipped():
    recs = [record(0, ErrorCode.SUCCESS, check=CLEAR, truth=FO),
            record(1, None, truth=FO, error="the graph died"),               # failed step: no answer
            record(2, ErrorCode.SUCCESS, truth=FO, check_error="bad names"),  # plan not checked: penetrating
            record(3, ErrorCode.SUCCESS, check=CLEAR, truth_error="planner failed"),   # truth unknown: counted
            record(4, ErrorCode.SUCCESS, check=CLEAR, error="crashed after the answer")]   # an error wins
    s = unseen.summarize(recs)
    assert s["targets"] == 5
    assert s["codes"]["NO_ANSWER"] == 2
    assert s["plans_unchecked"] == 1 and s["plans_penetrating_true_obstacles"] == 1
    assert s["unseen_plans"] == 3            # the two checked and the unchecked one
    assert s["truth_missing"] == 2
    # every target is feasible and observable here (two by their truth being unknown); reached: 0 and 3 only
    assert s["feasible_observable_targets"] == 5 and s["feasible_observable_reached"] == 2
    assert s["feasible_observable_success_rate"] == pytest.approx(0.4)
    assert any(c["unchecked"] and c["index"] == 2 for c in s["penetrating_cases"])


def test_no_target_at_all_is_a_rate_of_zero_not_none():
    s = unseen.summarize([])
    assert s["targets"] == 0 and s["feasible_observable_success_rate"] == 0.0
    assert unseen.judge(s)["feasible_observable_success_rate"]["met"] is False
