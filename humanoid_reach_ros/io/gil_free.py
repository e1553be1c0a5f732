"""Publishing without holding Python's interpreter lock.

``rclpy``'s ``Publisher.publish`` keeps the interpreter lock (GIL) through the DDS write. A
write that blocks therefore stops every thread of the process: in the executor's loop process
a Fast DDS write that blocked 5-10 ms often and ~333 ms a few times a session (the health
check of a fresh shared-memory port while a new ``reach_operator`` joins) stopped the solver
thread too, and the next step was late (an overrun). :class:`GilFreePublisher` does what
``publish`` does, in the same order, with the lock released for the write alone: the message
type's own C conversion (``_CONVERT_FROM_PY``, under the lock) into a C message, then
``rcl_publish`` through :mod:`ctypes` (a ``CDLL`` call releases the lock while it runs), then
the C message freed. A blocked write then blocks only the thread that writes. Same topic,
QoS and wire bytes as ``publish`` (tested); subscribers see no difference.

Where ``librcl`` or the type's capsules cannot be found (not Linux, another rclpy), it falls
back to ``publish`` and says so in :attr:`GilFreePublisher.mode`.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
from typing import Any


class _ErrorString(ctypes.Structure):     # rcutils_error_string_t
    _fields_ = [("str", ctypes.c_char * 1024)]


def _loaded_library(name: str) -> str | None:
    """The path of ``name`` (e.g. ``librcl.so``) as this process loaded it (rclpy's), else the
    linker's search."""
    try:
        with open("/proc/self/maps") as f:
            for line in f:
                path = line.rsplit(None, 1)[-1]
                base = path.rsplit("/", 1)[-1]
                if base == name or base.startswith(name + "."):
                    return path
    except OSError:
        pass
    return ctypes.util.find_library(name[3:].split(".so")[0])


@functools.lru_cache(maxsize=1)
def _functions() -> tuple[Any, Any, Any] | str:
    """(rcl_publish, rcutils_get_error_string, rcutils_reset_error), or why not."""
    import rclpy  # noqa: F401  (loads librcl and librcutils into the process)
    paths = {n: _loaded_library(n) for n in ("librcl.so", "librcutils.so")}
    if not all(paths.values()):
        return f"not found in this process: {', '.join(n for n, p in paths.items() if not p)}"
    try:
        rcl, rcutils = ctypes.CDLL(paths["librcl.so"]), ctypes.CDLL(paths["librcutils.so"])
        publish = rcl.rcl_publish
        get_error, reset_error = rcutils.rcutils_get_error_string, rcutils.rcutils_reset_error
    except (OSError, AttributeError) as exc:
        return f"{type(exc).__name__}: {exc}"
    publish.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
    publish.restype = ctypes.c_int32
    get_error.argtypes, get_error.restype = [], _ErrorString
    reset_error.argtypes, reset_error.restype = [], None
    return publish, get_error, reset_error


@functools.lru_cache(maxsize=None)
def _message_functions(msg_type: type) -> tuple[Any, Any, Any] | str:
    """The type's (create, convert_from_py, destroy) C functions from its support capsules, or
    why not. ``convert_from_py`` takes Python objects: called with the lock held (``PYFUNCTYPE``)."""
    from rclpy.type_support import check_for_type_support
    try:
        check_for_type_support(msg_type)
        meta = type(msg_type)
        get = ctypes.pythonapi.PyCapsule_GetPointer
        get.argtypes, get.restype = [ctypes.py_object, ctypes.c_char_p], ctypes.c_void_p
        create = ctypes.CFUNCTYPE(ctypes.c_void_p)(get(meta._CREATE_ROS_MESSAGE, None))
        convert = ctypes.PYFUNCTYPE(ctypes.c_bool, ctypes.py_object, ctypes.c_void_p)(
            get(meta._CONVERT_FROM_PY, None))
        destroy = ctypes.CFUNCTYPE(None, ctypes.c_void_p)(get(meta._DESTROY_ROS_MESSAGE, None))
    except (AttributeError, TypeError, ValueError) as exc:
        return f"no C support capsules for {msg_type.__name__}: {type(exc).__name__}: {exc}"
    return create, convert, destroy


def releases_the_gil(function: Any) -> bool:
    """Whether a ctypes foreign function releases the interpreter lock while it runs (a
    ``CDLL`` function does; a ``PyDLL`` one does not)."""
    return not (function._flags_ & ctypes._FUNCFLAG_PYTHONAPI)


class GilFreePublisher:
    """``publish(msg)`` as an rclpy ``Publisher``'s, without the interpreter lock during the
    DDS write (module docstring). ``mode`` is ``"gil-free"`` or ``"rclpy (<why>)"``."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher
        found = _functions()
        message = _message_functions(publisher.msg_type) if not isinstance(found, str) else found
        if isinstance(message, str):
            self._rcl_publish = None
            self.mode = f"rclpy ({message})"
        else:
            self._rcl_publish, self._get_error, self._reset_error = found
            self._create, self._convert, self._destroy = message
            self.mode = "gil-free"

    @property
    def topic_name(self) -> str:
        return self.publisher.topic_name

    def publish(self, msg: Any) -> None:
        if self._rcl_publish is None:
            self.publisher.publish(msg)
            return
        if not isinstance(msg, self.publisher.msg_type):
            raise TypeError(f"{self.publisher.topic_name} takes {self.publisher.msg_type.__name__}, "
                            f"not {type(msg).__name__}")
        c_msg = self._create()
        if not c_msg:
            raise MemoryError(f"could not allocate a {self.publisher.msg_type.__name__}")
        try:
            if not self._convert(msg, c_msg):
                raise ValueError(f"could not convert the {self.publisher.msg_type.__name__} for "
                                 f"{self.publisher.topic_name}")
            handle = self.publisher.handle
            with handle:                      # not destroyed while it writes
                ret = self._rcl_publish(handle.pointer, c_msg, None)
        finally:
            self._destroy(c_msg)
        if ret != 0:
            text = self._get_error().str.decode(errors="replace")
            self._reset_error()
            raise RuntimeError(f"publishing on {self.publisher.topic_name} failed ({ret}): {text}")


__all__ = ["GilFreePublisher", "releases_the_gil"]
