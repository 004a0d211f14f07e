"""Whether a process still runs, one rule for every part of fleetbus that asks (psutil)."""

from __future__ import annotations

import psutil


def pid_alive(pid: object) -> bool:
    """Whether ``pid`` is a live process. A zombie counts as gone: it has ended, and only its
    parent may reap it. Someone else's process counts as alive."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
    except psutil.AccessDenied:
        return True
