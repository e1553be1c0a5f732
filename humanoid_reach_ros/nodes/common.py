"""What every node of the package shares: declared parameters and a clean ``main``.

* ``declare_parameters`` (of ``params.ParamSpec`` tables): a table of parameters with defaults, descriptions,
  ranges and read-only flags, declared with ROS parameter descriptors (so ``ros2 param
  describe`` shows them and out-of-range values are refused by rclpy).
* ``run_node``: ``rclpy.init``, construct, spin, and stop cleanly on Ctrl-C / SIGTERM
  (exit 0, no traceback); a configuration error exits 2 with one FATAL log line.
"""
from __future__ import annotations

import time
from typing import Any, Callable, Mapping

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.logging import get_logger
from rclpy.node import Node

from humanoid_reach_ros.params import ParamSpec


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS parameter descriptor of ``spec`` (``ros2 param describe``; rclpy refuses a value
    out of its range)."""
    d = ParameterDescriptor(description=spec.description, read_only=spec.read_only,
                            additional_constraints=spec.constraints)
    if spec.range is not None and isinstance(spec.default, int) and not isinstance(spec.default, bool):
        d.integer_range = [IntegerRange(from_value=int(spec.range[0]), to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
    return d


def declare_parameters(node: Node, table: Mapping[str, ParamSpec]) -> dict[str, Any]:
    """Declare every parameter of ``table`` with its descriptor; returns the values in effect."""
    for name, spec in table.items():
        node.declare_parameter(name, spec.default, descriptor(spec))
    return {name: node.get_parameter(name).value for name in table}


def context_shutting_down(wait_s: float = 1.0, context=None) -> bool:
    """Whether the rclpy context is shut down or becomes so within ``wait_s`` (a signal
    handler shuts it down asynchronously, so an exception raised by that shutdown can
    precede ``rclpy.ok()`` turning false)."""
    deadline = time.monotonic() + wait_s
    while rclpy.ok(context=context):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def run_node(make_node: Callable[[], Node], name: str, args: list[str] | None = None,
             executor: Callable[[], Executor] | None = None) -> int:
    """Run a node until Ctrl-C / SIGTERM; returns the process exit code.

    rclpy's signal handlers shut the context down asynchronously, so the executor can
    fail with an ``RCLError`` ("context is not valid") instead of raising
    ``ExternalShutdownException`` when the signal lands while it builds its wait set;
    any exception after the context is shut down therefore counts as a clean stop. The
    exception can come a moment before ``rclpy.ok()`` turns false (seen: a subscription's
    ``take_message`` failing while the context was shut down), hence
    :func:`context_shutting_down`.
    """
    rclpy.init(args=args)
    try:
        try:
            node = make_node()
        except (ParameterException, ValueError, OSError, KeyError) as exc:  # bad parameters or files
            get_logger(name).fatal(f"cannot start: {type(exc).__name__}: {exc}")
            return 2
        try:
            if executor is None:
                rclpy.spin(node)
            else:
                ex = executor()
                ex.add_node(node)
                ex.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception:
            if not context_shutting_down():
                raise
        finally:
            node.destroy_node()
    except KeyboardInterrupt:  # Ctrl-C during start-up
        pass
    finally:
        rclpy.try_shutdown()
    return 0


def scene_file_voxels(path: str, resolution_m: float, exclude_groups) -> Any:
    """A scene file's voxels (N, 3), the map until a /voxel_map arrives: the nodes read the
    file, the planning scene (scene/planning_scene.py) only ever gets points."""
    from humanoid_reach_ros.sim.scene import load_scene
    return load_scene(str(path)).voxelize(resolution_m, exclude_groups=tuple(exclude_groups))

