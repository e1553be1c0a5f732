"""bench/peers without the peers: the problem it exports and the JSON it assembles.

Project venv only (no .venv-peers / .venv-placo needed): imports bench/peers/problem.py
and bench/peers/report.py, checks the ratio arithmetic and the JSON assembly on fake
timings, and the common goal check on the project's own goals.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

PEERS = Path(__file__).resolve().parents[1] / "bench" / "peers"
sys.path.insert(0, str(PEERS))

import report  # noqa: E402


def test_ratio_is_peer_over_ours_and_none_when_missing():
    assert report.ratio(30.0, 10.0) == pytest.approx(3.0)
    assert report.ratio(None, 10.0) is None
    assert report.ratio(5.0, None) is None
    assert report.ratio(float("inf"), 1.0) is None
    assert report.ratio(1.0, 0.0) is None
    assert report.per_valid_goal_ms(2.0, 4) == pytest.approx(500.0)
    assert report.per_valid_goal_ms(2.0, 0) is None


def test_assemble_on_fake_timings():
    ours = {"goals": {"time_per_valid_goal_ms": 10.0}, "paths": {"plan_ms_mean": 100.0},
            "collision": {"single_us_per_config": 5.0}}
    peers = {
        "hpp": {"goals": {"available": True, "time_per_valid_goal_ms": 50.0},
                "paths": {"available": True, "time_s": [0.2, 0.4]},
                "collision": {"available": True, "us_per_config": 50.0}},
        "placo": {"goals": {"available": False, "why": "import failed"}},
        "pink": {"goals": {"available": True, "time_per_valid_goal_ms": 200.0}},
        "ompl": {"paths": {"available": True, "ours": {"time_s": [0.1, 0.1]}, "ompl": {"time_s": [0.3, 0.5]}}},
        "coal": {"collision": {"available": True, "us_per_config": 20.0}},
    }
    out = report.assemble(ours, peers, "fake machine", {"seed": 1})
    assert out["ratio_goal_vs_hpp"] == pytest.approx(5.0)
    assert out["ratio_goal_vs_placo"] is None
    assert out["ratio_goal_vs_pink"] == pytest.approx(20.0)
    assert out["ratio_path_vs_ompl"] == pytest.approx(4.0)     # vs our run interleaved in the OMPL worker
    assert out["ratio_path_vs_hpp"] == pytest.approx(3.0)
    assert out["ratio_collision_vs_hpp"] == pytest.approx(10.0)
    assert out["ratio_collision_vs_coal"] == pytest.approx(4.0)
    assert out["machine"] == "fake machine"
    assert set(report.RATIO_KEYS) <= set(out)
    line = json.dumps(out)                       # one JSON line, round trip
    assert json.loads(line)["peers"]["placo"]["goals"]["why"] == "import failed"


def test_assemble_with_no_peer_at_all():
    out = report.assemble({}, {}, "m")
    assert all(out[k] is None for k in report.RATIO_KEYS)


def test_problem_export_and_common_goal_check(tmp_path):
    import problem as PB
    from humanoid_reach_ros.planning.goal_sampler import sample_goals

    prob = PB.build_problem()
    meta = PB.write_problem(prob, tmp_path, n_seeds=4)
    P = np.load(tmp_path / "problem.npz")
    assert P["q_seed"].shape == (4, prob.robot.model.nq) and P["targets"].shape == (4, 4, 4)
    assert np.all(P["q_seed"][:, 7:] >= prob.robot.lower) and np.all(P["q_seed"][:, 7:] <= prob.robot.upper)
    assert prob.region.contains(P["targets"][:, :3, 3], P["targets"][:, :3, :3]).all()
    for f in ("hrp2_capsules.urdf", "hrp2_capsules.srdf", "scene.urdf"):
        assert (tmp_path / f).stat().st_size > 0
    urdf = (tmp_path / "hrp2_capsules.urdf").read_text()
    cm = prob.planner.collision_model
    n_caps = int(np.sum(np.linalg.norm(np.asarray(cm.p1_local) - np.asarray(cm.p0_local), axis=1) > 1e-9))
    assert urdf.count("<collision") == 2 * cm.n_shapes + n_caps
    assert "valve" not in (tmp_path / "scene.urdf").read_text()
    assert meta["locked_joints"]["right_arm"][0].startswith("RARM")
    # the project's goals pass the common check; the random seeds do not
    goals = sample_goals(prob.region, 3, prob.robot, prob.collision, np.random.default_rng(1),
                         projector=prob.projector)
    assert PB.goal_validity(prob, goals.q)["n_valid"] == 3
    chk = PB.goal_validity(prob, P["q_seed"])
    assert chk["n_valid"] == 0 and chk["failures"]["hand_not_in_wgr"] == 4
