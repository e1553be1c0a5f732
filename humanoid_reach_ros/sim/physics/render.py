"""Pictures of the robot in its scene: MuJoCo's offscreen renderer on the physics model.

:func:`render_states` places the model at measured states (joints and floating base, as
``/joint_states`` and ``/base_pose`` carry them: no simulation here) and renders each from a
free camera aimed at the robot and the scene's target. The renderer needs an OpenGL context
without a display: ``MUJOCO_GL=egl`` (Mesa's EGL, Debian packages ``libegl1 libegl-mesa0
libgl1-mesa-dri``; it renders on the CPU where no GPU is) is set here unless the caller chose
one (``osmesa`` needs ``libosmesa6``, missing on this machine); MuJoCo reads the variable when it
is first imported, so import this module before anything imports ``mujoco`` in a process that
renders. :func:`gl_problem` says why rendering cannot work here, or None.

No ROS here.
"""
from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Sequence  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from humanoid_reach_ros.sim.physics.model_builder import PhysicsModel, base_pose_from_se3  # noqa: E402

GL_PACKAGES = {"egl": "libegl1 libegl-mesa0 libgl1-mesa-dri", "osmesa": "libosmesa6"}


@dataclass(frozen=True)
class View:
    """A free camera: it looks at ``lookat`` [m, world] from ``distance_m``, turned ``azimuth_deg``
    about the vertical (0: from +x looking back along -x ... MuJoCo's convention) and
    ``elevation_deg`` (negative: from above)."""

    lookat: tuple[float, float, float]
    distance_m: float = 2.6
    azimuth_deg: float = 150.0
    elevation_deg: float = -18.0


def gl_problem() -> str | None:
    """None when an offscreen context can be made here, else why not (and what to install)."""
    backend = os.environ.get("MUJOCO_GL", "egl")
    try:
        model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
        r = mujoco.Renderer(model, 16, 16)
        r.close()
    except Exception as exc:  # noqa: BLE001 -- any failure of the GL stack is the answer
        need = GL_PACKAGES.get(backend, "an OpenGL implementation")
        return (f"MuJoCo cannot render offscreen with MUJOCO_GL={backend}: {type(exc).__name__}: {exc} "
                f"(install {need})")
    return None


def default_view(pm: PhysicsModel, target: np.ndarray | None) -> View:
    """Aimed between the robot's waist and ``target`` (the scene's target), from the front left,
    far enough to see the robot whole (its height plus a margin)."""
    height = float(pm.robot.base_on_feet(pm.robot.half_sitting_joints).translation[2])
    centre = np.array([0.0, 0.0, height])
    if target is not None:
        centre = 0.5 * (centre + np.asarray(target, float))
    return View(lookat=(float(centre[0]), float(centre[1]), float(centre[2])), distance_m=2.2 * height + 1.0)


def render_states(pm: PhysicsModel, states: Sequence[tuple[np.ndarray, pin.SE3]], view: View,
                  width: int = 640, height: int = 480) -> list[np.ndarray]:
    """RGB images (height, width, 3) of the model at each ``(joints [model order], base pose)``."""
    data = mujoco.MjData(pm.model)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = view.lookat
    cam.distance, cam.azimuth, cam.elevation = view.distance_m, view.azimuth_deg, view.elevation_deg
    out = []
    with mujoco.Renderer(pm.model, height, width) as renderer:
        for joints, base in states:
            data.qpos[:7] = base_pose_from_se3(base)
            data.qpos[pm.qpos_adr] = joints
            mujoco.mj_forward(pm.model, data)
            renderer.update_scene(data, camera=cam)
            out.append(renderer.render().copy())
    return out


def write_frames(images: Sequence[np.ndarray], labels: Sequence[str], out_dir: Path, stem: str = "frame") -> list[Path]:
    """Each image as ``<stem>_<k>.png`` with its label written in, plus ``<stem>s.png``: all of
    them side by side (a contact sheet). Returns the paths written."""
    import cv2

    out_dir.mkdir(parents=True, exist_ok=True)
    paths, tiles = [], []
    for k, (img, label) in enumerate(zip(images, labels)):
        bgr = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)
        cv2.putText(bgr, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
        path = out_dir / f"{stem}_{k:02d}.png"
        cv2.imwrite(str(path), bgr)
        paths.append(path)
        tiles.append(bgr)
    if tiles:
        sheet = out_dir / f"{stem}s.png"
        cv2.imwrite(str(sheet), np.hstack(tiles))
        paths.append(sheet)
    return paths


__all__ = ["GL_PACKAGES", "View", "default_view", "gl_problem", "render_states", "write_frames"]
