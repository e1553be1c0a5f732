"""Torso posture regression (dissertation Sec. 4.1, Algorithm 2, Table 1)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.dual_arm.torso_regression import (
    ReachWorkspace, TorsoRegression, generate_dataset,
)
from humanoid_reach_ros.dual_arm.upper_body_ik import UpperBodyIK
from humanoid_reach_ros.dual_arm.whole_body_ik import lowered_initial_posture
from humanoid_reach_ros.robot.model import RobotModel


@pytest.fixture(scope="module")
def reg():
    return TorsoRegression.load(RobotModel().spec.torso_regression)


@pytest.fixture(scope="module")
def ws():
    return ReachWorkspace.load()


def test_shipped_model_small_with_table1_parameters(reg):
    npz = config_path(RobotModel().spec.torso_regression + ".npz")
    assert npz.stat().st_size < 2_000_000
    m = reg.meta
    assert m["kernel_width_m"] == pytest.approx(0.1)
    assert m["gamma"] == pytest.approx(1.0 / (2 * 0.1 ** 2))
    assert m["C"] == pytest.approx(1.0) and m["epsilon"] == pytest.approx(1e-4)
    assert m["n_train"] >= 100 and m["n_tried"] >= m["n_train"]


def test_predicts_training_pairs_within_training_error(reg, ws):
    """Regenerate the first training pairs (same seed, Algorithm 2 is deterministic)."""
    robot = RobotModel()
    q0 = lowered_initial_posture(robot, ws.initial_com_drop_m)
    pr, pl = ws.sample(np.random.default_rng(int(reg.meta["seed"])), int(reg.meta["n_tried"]))
    ik = UpperBodyIK(robot)
    d = ws.dataset
    X, Y = [], []
    for a, b in zip(pr[:8], pl[:8]):       # the first pairs Algorithm 2 tried
        chest, _ = ik.generate_sample(q0, ws.targets(a, b), float(d["omega0"]), int(d["max_tries"]),
                                      float(d["tol"]), int(d["max_iter"]))
        if chest is not None:
            X.append(np.concatenate([a, b]))
            Y.append(chest)
    assert len(X) >= 1
    X, Y = np.array(X), np.array(Y)
    err = np.abs(reg.predict_batch(X) - Y).max()
    assert err <= reg.meta["train_max_abs_rad"] + 1e-9
    for x, y in zip(X, Y):
        np.testing.assert_allclose(reg.predict(x[:3], x[3:]), y, atol=reg.meta["train_max_abs_rad"] + 1e-9)


def test_numpy_prediction_equals_sklearn(tmp_path):
    from sklearn.svm import SVR
    rng = np.random.default_rng(0)
    X = rng.uniform(-0.3, 0.3, (60, 6))
    Y = np.stack([np.sin(3 * X[:, 0]) + X[:, 5], np.cos(2 * X[:, 4])], 1)
    reg = TorsoRegression.fit(X, Y, 0.1, 1.0, 1e-4)
    Xt = rng.uniform(-0.3, 0.3, (20, 6))
    for k in range(2):
        ref = SVR(kernel="rbf", gamma=50.0, C=1.0, epsilon=1e-4).fit(X, Y[:, k]).predict(Xt)
        np.testing.assert_allclose(reg.predict_batch(Xt)[:, k], ref, atol=1e-9)
    # save / load round trip (absolute stem)
    reg.save(tmp_path / "m")
    back = TorsoRegression.load(tmp_path / "m")
    np.testing.assert_allclose(back.predict_batch(Xt), reg.predict_batch(Xt), atol=0)
    assert yaml.safe_load((tmp_path / "m.yaml").read_text())["n_train"] == 60


def test_generate_dataset_small(ws):
    robot = RobotModel()
    q0 = lowered_initial_posture(robot, ws.initial_com_drop_m)
    X, Y, tried = generate_dataset(robot, ws, q0, 3, seed=1)
    assert tried == 3 and X.shape[1] == 6 and Y.shape == (len(X), 2) and np.all(np.isfinite(Y))


def test_bad_inputs(reg, tmp_path):
    with pytest.raises(ValueError, match="finite"):
        reg.predict([np.nan, 0, 1], [0.3, 0.2, 1.0])
    with pytest.raises(ValueError, match="3-vectors"):
        reg.predict([0.3, 0.1], [0.3, 0.2, 1.0])
    with pytest.raises(ValueError, match=r"\(n, 6\)"):
        reg.predict_batch(np.zeros((3, 5)))
    with pytest.raises(ValueError, match="X"):
        TorsoRegression.fit(np.zeros((5, 6)), np.zeros((4, 2)))
    with pytest.raises(FileNotFoundError, match="train_torso_regression"):
        TorsoRegression.load(tmp_path / "missing")
    np.savez(tmp_path / "broken.npz", gamma=1.0)
    (tmp_path / "broken.yaml").write_text("{}\n")
    with pytest.raises(ValueError, match="missing array"):
        TorsoRegression.load(tmp_path / "broken")
    (tmp_path / "ws.yaml").write_text("workspace: {}\n")
    with pytest.raises(ValueError, match="malformed"):
        ReachWorkspace.load(tmp_path / "ws.yaml")


def test_workspace_boxes_are_sec41(ws):
    size = np.maximum(ws.right_upper, ws.left_upper) - np.minimum(ws.right_lower, ws.left_lower)
    np.testing.assert_allclose(size, [0.45, 0.8, 0.75], atol=1e-12)
    rng = np.random.default_rng(1)
    pr, pl = ws.sample(rng, 50)
    assert np.all((pr >= ws.right_lower) & (pr <= ws.right_upper))
    t = ws.targets(pr[0], pl[0])
    # tool axis (-z of the hand) points from the shoulder to the target
    u = (pr[0] - ws.origin_right) / np.linalg.norm(pr[0] - ws.origin_right)
    np.testing.assert_allclose(-t.R_right[:, 2], u, atol=1e-12)
