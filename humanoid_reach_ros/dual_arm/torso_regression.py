"""Torso posture regression (dissertation Sec. 4.1, Algorithm 2, Table 1).

Input ``x = (x_1, y_1, z_1, x_2, y_2, z_2)``: the target positions of the right and left
hand [m, world frame of the initial posture]; output ``(q_chest_pitch, q_chest_yaw)``
[rad]. One epsilon-SVR with the Gaussian (RBF) kernel per output (scikit-learn ``SVR``),
Table 1 parameters: kernel width ``sigma = 0.1`` m (``gamma = 1 / (2 sigma^2)`` -- the
dissertation gives the width, not gamma), constraint ``C = 1.0``, slack ``epsilon = 1e-4``.

Dataset (Algorithm 2): hand target pairs uniform in the workspace boxes (Sec. 4.1: one box
0.45 x 0.8 x 0.75 m in front of the robot, split at y = 0 between the hands), fixed hand
orientations -- the robot's workspace file (robot.yaml ``dual_arm_workspace``, e.g.
``config/robots/hrp2/dual_arm_workspace.yaml``: the box, orientation origins and initial CoM
drop are fitted to one robot's arms and legs, see :meth:`ReachWorkspace.for_robot`) --, each solved by the
LM *BothArmsIK* from the initial posture with the torso height fixed; unsolvable pairs are
dropped and only the chest angles of the solved ones are kept. The dissertation does not
state its dataset size; ours is in the YAML (3,000 pairs tried by default).

Saved model: ``<stem>.npz`` (support vectors, dual coefficients, intercepts, gamma per
output) and ``<stem>.yaml`` (hyper-parameters, dataset size, training error). Online
prediction (:meth:`TorsoRegression.predict`) evaluates the RBF expansion with numpy
``f(x) = sum_i a_i exp(-gamma |x - s_i|^2) + b`` -- the same function sklearn's
``SVR.predict`` computes, without its per-call overhead; the test checks both agree.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from humanoid_reach_ros.paths import config_path
from humanoid_reach_ros.dual_arm.targets import HandTargets
from humanoid_reach_ros.dual_arm.lower_body_ik import lowered_initial_posture
from humanoid_reach_ros.dual_arm.upper_body_ik import UpperBodyIK
from humanoid_reach_ros.robot.model import N_BASE_Q, RobotModel
from humanoid_reach_ros.robot.spec import DEFAULT_DUAL_ARM_WORKSPACE

#: the workspace file of a robot description without ``dual_arm_workspace``
WORKSPACE_YAML = DEFAULT_DUAL_ARM_WORKSPACE


@dataclass(frozen=True, eq=False)
class ReachWorkspace:
    """Workspace boxes, hand orientations, initial CoM drop, eq. 6 offset, SVR + dataset params."""

    right_lower: np.ndarray
    right_upper: np.ndarray
    left_lower: np.ndarray
    left_upper: np.ndarray
    R_right: np.ndarray
    R_left: np.ndarray
    origin_right: np.ndarray
    origin_left: np.ndarray
    initial_com_drop_m: float
    com_offset_m: float
    svr: dict
    dataset: dict
    #: joint -> angle [rad] of the initial posture that differ from half-sitting (optional
    #: ``initial_joints_deg``; e.g. arms moved off a singular half-sitting posture)
    initial_joints: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def load(cls, path: str | Path = WORKSPACE_YAML) -> "ReachWorkspace":
        p = config_path(str(path))
        with open(p) as f:
            y = yaml.safe_load(f)
        try:
            ws = y["workspace"]
            box = {s: (np.array(ws[s]["lower_m"], float), np.array(ws[s]["upper_m"], float)) for s in ("right", "left")}
            rot = {s: _rpy(y["hand_rpy_deg"][s]) for s in ("right", "left")}
            org = {s: np.array(y["orientation_origin_m"][s], float) for s in ("right", "left")}
            joints = {str(k): float(np.radians(float(v))) for k, v in (y.get("initial_joints_deg") or {}).items()}
            out = cls(box["right"][0], box["right"][1], box["left"][0], box["left"][1], rot["right"], rot["left"],
                      org["right"], org["left"], float(y["initial_com_drop_m"]), float(y["com_offset_m"]),
                      dict(y["svr"]), dict(y["dataset"]), joints)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"{p}: malformed workspace file ({exc!r})") from exc
        for lo, hi in ((out.right_lower, out.right_upper), (out.left_lower, out.left_upper)):
            if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
                raise ValueError(f"{p}: each box needs lower_m < upper_m, 3 values each")
        if not all(np.isfinite(v) for v in out.initial_joints.values()):
            raise ValueError(f"{p}: initial_joints_deg must map joint names to finite angles [deg]")
        return out

    def initial_posture(self, robot: RobotModel) -> np.ndarray:
        """The initial posture (nq): half-sitting with ``initial_joints`` set, the CoM lowered
        by ``initial_com_drop_m``. ``ValueError`` naming a joint the robot lacks or a value
        outside its limits."""
        q = robot.half_sitting()
        for name, v in self.initial_joints.items():
            if name not in robot.joint_index:
                raise ValueError(f"workspace initial_joints_deg: robot {robot.name!r} has no joint {name!r}")
            i = robot.joint_index[name]
            if not robot.lower[i] <= v <= robot.upper[i]:
                raise ValueError(f"workspace initial_joints_deg: {name} = {np.degrees(v):.1f} deg "
                                 "is outside its limits")
            q[N_BASE_Q + i] = v
        return lowered_initial_posture(robot, self.initial_com_drop_m, q)

    @classmethod
    def for_robot(cls, robot: RobotModel) -> "ReachWorkspace":
        """The workspace file the robot's description names (``dual_arm_workspace``)."""
        return cls.load(robot.spec.dual_arm_workspace)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``n`` right and ``n`` left target positions, uniform in the boxes."""
        return (rng.uniform(self.right_lower, self.right_upper, (n, 3)),
                rng.uniform(self.left_lower, self.left_upper, (n, 3)))

    def hand_rotation(self, side: str, p) -> np.ndarray:
        """``R*(p) = Rot(a -> u) R_base`` (workspace.yaml): the tool axis points from the
        orientation origin (shoulder) to the target."""
        Rb, o = (self.R_right, self.origin_right) if side == "right" else (self.R_left, self.origin_left)
        u = np.asarray(p, float) - o
        nu = np.linalg.norm(u)
        if not np.isfinite(nu) or nu < 1e-9:
            raise ValueError(f"{side} hand target must be finite and away from the shoulder, got {p}")
        a = -Rb[:, 2]
        u = u / nu
        v = np.cross(a, u)
        sv = np.linalg.norm(v)
        if sv < 1e-12:
            return Rb.copy() if a @ u > 0 else pin.exp3(np.pi * _perp(a)) @ Rb
        return pin.exp3(v / sv * np.arctan2(sv, float(a @ u))) @ Rb

    def targets(self, p_right, p_left) -> HandTargets:
        """Hand targets at these positions with the workspace's orientation rule."""
        return HandTargets.make(p_right, self.hand_rotation("right", p_right),
                                p_left, self.hand_rotation("left", p_left))


def _perp(a: np.ndarray) -> np.ndarray:
    v = np.cross(a, [1.0, 0.0, 0.0])
    if np.linalg.norm(v) < 1e-6:
        v = np.cross(a, [0.0, 1.0, 0.0])
    return v / np.linalg.norm(v)


def _rpy(deg) -> np.ndarray:
    r, p, y = np.radians(np.asarray(deg, float))
    return pin.utils.rpyToMatrix(r, p, y)


def generate_dataset(robot: RobotModel, ws: ReachWorkspace, q0: np.ndarray, n_samples: int,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """Algorithm 2 on ``n_samples`` random pairs: returns ``X (m, 6)``, ``Y (m, 2)``
    (pitch, yaw) of the ``m`` solvable pairs and the number tried."""
    ik = UpperBodyIK(robot)
    rng = np.random.default_rng(seed)
    pr, pl = ws.sample(rng, n_samples)
    d = ws.dataset
    X, Y = [], []
    for a, b in zip(pr, pl):
        chest, _ = ik.generate_sample(q0, ws.targets(a, b), omega0=float(d["omega0"]),
                                      max_tries=int(d["max_tries"]), tol=float(d["tol"]),
                                      max_iter=int(d["max_iter"]))
        if chest is not None:
            X.append(np.concatenate([a, b]))
            Y.append(chest)
    return np.array(X).reshape(-1, 6), np.array(Y).reshape(-1, 2), n_samples


@dataclass(frozen=True, eq=False)
class TorsoRegression:
    """Two RBF expansions (pitch, yaw): ``support[k] (n_k, 6)``, ``coef[k]``, ``intercept[k]``."""

    gamma: float
    support: tuple[np.ndarray, np.ndarray]
    coef: tuple[np.ndarray, np.ndarray]
    intercept: tuple[float, float]
    meta: dict

    @classmethod
    def fit(cls, X: np.ndarray, Y: np.ndarray, kernel_width_m: float = 0.1, C: float = 1.0,
            epsilon: float = 1e-4) -> "TorsoRegression":
        """Train one sklearn ``SVR(kernel="rbf")`` per output (Table 1 parameters)."""
        from sklearn.svm import SVR

        X = np.asarray(X, float)
        Y = np.asarray(Y, float)
        if X.ndim != 2 or X.shape[1] != 6 or Y.shape != (len(X), 2) or len(X) < 2:
            raise ValueError(f"need X (n, 6) and Y (n, 2) with n >= 2, got {X.shape} and {Y.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise ValueError("training data must be finite")
        gamma = 1.0 / (2.0 * kernel_width_m ** 2)
        sup, coef, icpt, rmse = [], [], [], []
        for k in range(2):
            svr = SVR(kernel="rbf", gamma=gamma, C=C, epsilon=epsilon).fit(X, Y[:, k])
            sup.append(np.array(svr.support_vectors_))
            coef.append(np.array(svr.dual_coef_[0]))
            icpt.append(float(svr.intercept_[0]))
            rmse.append(float(np.sqrt(np.mean((svr.predict(X) - Y[:, k]) ** 2))))
        meta = {"kernel_width_m": float(kernel_width_m), "gamma": gamma, "C": float(C),
                "epsilon": float(epsilon), "n_train": int(len(X)),
                "train_rmse_rad": {"pitch": rmse[0], "yaw": rmse[1]},
                "train_max_abs_rad": None, "outputs": ["chest pitch", "chest yaw"]}
        reg = cls(gamma, (sup[0], sup[1]), (coef[0], coef[1]), (icpt[0], icpt[1]), meta)
        meta["train_max_abs_rad"] = float(np.abs(reg.predict_batch(X) - Y).max())
        return reg

    def predict_batch(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[1] != 6:
            raise ValueError(f"regression input must have shape (n, 6), got {X.shape}")
        out = np.empty((len(X), 2))
        for k in range(2):
            d2 = ((X[:, None, :] - self.support[k][None]) ** 2).sum(-1)
            out[:, k] = np.exp(-self.gamma * d2) @ self.coef[k] + self.intercept[k]
        return out

    def predict(self, p_right, p_left) -> np.ndarray:
        """``(q_chest_pitch, q_chest_yaw)`` [rad] for one pair of hand positions."""
        x = np.concatenate([np.asarray(p_right, float).reshape(-1), np.asarray(p_left, float).reshape(-1)])
        if x.shape != (6,) or not np.all(np.isfinite(x)):
            raise ValueError(f"hand positions must be two finite 3-vectors, got {x.tolist()}")
        return self.predict_batch(x[None])[0]

    # ------------------------------------------------------------ files
    def save(self, stem: str | Path) -> tuple[Path, Path]:
        base = config_path(str(stem))
        base.parent.mkdir(parents=True, exist_ok=True)
        npz, yml = base.with_suffix(".npz"), base.with_suffix(".yaml")
        np.savez_compressed(npz, gamma=self.gamma, support_pitch=self.support[0], support_yaw=self.support[1],
                            coef_pitch=self.coef[0], coef_yaw=self.coef[1], intercept=np.array(self.intercept))
        with open(yml, "w") as f:
            f.write("# Torso posture regression (dissertation Sec. 4.1, Table 1); written by\n"
                    "# tools/train_torso_regression.py -- do not edit, regenerate.\n")
            yaml.safe_dump(self.meta, f, sort_keys=False)
        return npz, yml

    @classmethod
    def load(cls, stem: str | Path) -> "TorsoRegression":
        base = config_path(str(stem))
        npz, yml = base.with_suffix(".npz"), base.with_suffix(".yaml")
        if not npz.is_file() or not yml.is_file():
            raise FileNotFoundError(f"torso regression files missing: {npz} / {yml} "
                                    "(run tools/train_torso_regression.py)")
        with np.load(npz) as z:
            try:
                gamma = float(z["gamma"])
                sup = (z["support_pitch"], z["support_yaw"])
                coef = (z["coef_pitch"], z["coef_yaw"])
                icpt = tuple(float(v) for v in z["intercept"])
            except KeyError as exc:
                raise ValueError(f"{npz}: missing array {exc}") from exc
        for s, c in zip(sup, coef):
            if s.ndim != 2 or s.shape[1] != 6 or c.shape != (len(s),):
                raise ValueError(f"{npz}: inconsistent support vectors / coefficients")
        with open(yml) as f:
            meta = yaml.safe_load(f) or {}
        return cls(gamma, sup, coef, (icpt[0], icpt[1]), meta)
