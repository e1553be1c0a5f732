"""The kinematics package (issue 23): one limb-solver protocol, a registry that picks each
limb's solver from its chain's structure, and every solver answering the protocol."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_reach_ros import kinematics
from humanoid_reach_ros.kinematics import LimbIKSet, LimbSolver, LimbStructureError, limb_solver
from humanoid_reach_ros.robot.model import RobotModel
from humanoid_reach_ros.robot.spec import robots

#: (robot, limb) -> the solver kind the registry must pick, from the chain's structure
EXPECTED_KINDS = {
    "hrp2": {"right_leg": "leg", "left_leg": "leg", "right_arm": "arm", "left_arm": "arm"},
    "talos": {"right_leg": "leg", "left_leg": "leg", "right_arm": "redundant", "left_arm": "redundant"},
    "g1": {"right_leg": "numerical", "left_leg": "numerical", "right_arm": "numerical", "left_arm": "numerical"},
}


@pytest.fixture(scope="module", params=robots())
def robot(request):
    return RobotModel(request.param)


def test_every_limb_of_every_robot_answers_the_protocol(robot):
    """Each shipped robot's four limbs: a solver of the kind its structure calls for, an
    instance of the protocol, and its answers through the protocol round-trip: the tip pose
    of the reference posture is solved back to a posture reaching it."""
    ik = LimbIKSet(robot)
    assert set(ik.names) == {"right_leg", "left_leg", "right_arm", "left_arm"}
    if robot.name in EXPECTED_KINDS:
        assert {n: ik[n].kind for n in ik.names} == EXPECTED_KINDS[robot.name]
    q = robot.half_sitting()
    for name in ik.names:
        solver = ik[name]
        assert isinstance(solver, LimbSolver), name
        spec = robot.limbs[name]
        root, tip = robot.frame_pose(q, spec.root), robot.frame_pose(q, spec.tip)
        res = solver.solve(root.translation, root.rotation, tip.translation, tip.rotation)
        assert res.ok.all(), (name, res.failure_counts())
        p, R = solver.fk(root.translation, root.rotation, res.q)
        np.testing.assert_allclose(p[0], tip.translation, atol=1e-8)
        np.testing.assert_allclose(R[0], tip.rotation, atol=1e-8)
        assert solver.maybe_reachable(root.translation, root.rotation, tip.translation, tip.rotation).all()
        points, slack, reach = solver.reach_centres()
        assert points.shape[1] == 3 and slack >= 0.0 and reach > 0.0


def test_the_registry_tries_its_solvers_in_order_and_names_every_reason():
    """``SOLVERS`` in order: the hand-derived closed form, then the general closed form (which
    falls back to the numerical solver); a limb no solver accepts (here HRP-2's arm cut to 5
    joints) is refused with each solver's reason."""
    import dataclasses

    assert [what for what, _ in kinematics.SOLVERS] == ["hand-derived closed form",
                                                        "general closed form, else numerical"]
    hrp2 = RobotModel("hrp2")
    assert limb_solver(hrp2, "right_leg").kind == "leg"
    spec = hrp2.limbs["right_arm"]
    hrp2.limbs["right_arm"] = dataclasses.replace(spec, joints=spec.joints[:5], joint_index=spec.joint_index[:5])
    with pytest.raises(LimbStructureError) as exc:
        limb_solver(hrp2, "right_arm")
    text = str(exc.value)
    assert "hand-derived closed form:" in text and "general closed form, else numerical:" in text
    assert "6 joints" in text
