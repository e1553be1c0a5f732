"""Real-time scheduling of the calling thread where the OS allows it.

``make_thread_realtime(priority)`` asks for ``SCHED_FIFO`` at ``priority`` for the calling
thread (Linux applies ``sched_setscheduler(0, ...)`` to the calling thread);
``lock_memory()`` locks the process's pages (``mlockall(MCL_CURRENT | MCL_FUTURE)``) so a
page fault never delays a deadline. Both answer ``(ok, message)``: where the OS refuses
(no ``CAP_SYS_NICE`` / ``RLIMIT_RTPRIO`` = 0, ``RLIMIT_MEMLOCK`` too small, not Linux) the
caller logs the message once as a warning and runs at normal priority. A deployment grants
them with ``/etc/security/limits.d`` (``@realtime - rtprio 98``, ``@realtime - memlock
unlimited``) or ``CAP_SYS_NICE`` / ``CAP_IPC_LOCK`` on the executable.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

MCL_CURRENT, MCL_FUTURE = 1, 2


def make_thread_realtime(priority: int) -> tuple[bool, str]:
    """SCHED_FIFO at ``priority`` (1..99) for the calling thread; ``priority <= 0`` leaves it."""
    if priority <= 0:
        return False, "real-time priority disabled (rt_priority = 0)"
    if not hasattr(os, "sched_setscheduler"):
        return False, "SCHED_FIFO is not available on this OS"
    try:
        prio = min(int(priority), os.sched_get_priority_max(os.SCHED_FIFO))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        return True, f"SCHED_FIFO priority {prio}"
    except (PermissionError, OSError) as exc:
        return False, (f"SCHED_FIFO priority {priority} refused ({exc.strerror or exc}); running at normal "
                       "priority: grant rtprio (limits.conf) or CAP_SYS_NICE for real-time deadlines")


#: a thread that shares the interpreter lock with a real-time loop runs this far below it
FEEDER_PRIORITY_BELOW = 20
#: interpreter lock hand-over interval of a process with a real-time loop [s] (Python's default: 5 ms)
REALTIME_SWITCH_INTERVAL_S = 0.0005


def make_feeder_thread_realtime(loop_priority: int) -> tuple[bool, str]:
    """SCHED_FIFO ``FEEDER_PRIORITY_BELOW`` under ``loop_priority`` (at least 1) for the calling
    thread, one that shares the interpreter lock with a real-time loop: at normal priority a
    busy machine can deschedule it *while it holds the lock*, and the loop then waits on it
    (priority inversion: the lock does not inherit priority). ``loop_priority <= 0`` leaves it."""
    if loop_priority <= 0:
        return make_thread_realtime(0)
    return make_thread_realtime(max(loop_priority - FEEDER_PRIORITY_BELOW, 1))


def lock_memory() -> tuple[bool, str]:
    """mlockall(MCL_CURRENT | MCL_FUTURE) for the whole process."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
            err = ctypes.get_errno()
            return False, (f"mlockall refused ({os.strerror(err)}); pages may fault: grant memlock (limits.conf) "
                           "or CAP_IPC_LOCK")
        return True, "memory locked (mlockall)"
    except (OSError, AttributeError) as exc:
        return False, f"mlockall unavailable ({exc})"


__all__ = ["make_thread_realtime", "make_feeder_thread_realtime", "lock_memory", "FEEDER_PRIORITY_BELOW",
           "REALTIME_SWITCH_INTERVAL_S"]
