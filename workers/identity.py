"""Who holds a lease: ``<host>:<pid>:<token>``, and whether that holder is known to be dead.

A worker killed with SIGKILL cannot give its leases back; they expire after their time. When its
successor runs on the same host, though, it can tell at once that the old process is gone, and
take the leases over without waiting: that keeps a restarted single worker as quick as before.
"""

from __future__ import annotations

import os
import socket
import uuid

from fleetbus.processes import pid_alive

#: Holders created by this process that are still running (a token each), so that a second
#: worker in the same process is not mistaken for a dead one.
_LIVE_HERE: set[str] = set()


def new_holder(kind: str = "worker") -> str:
    """A holder name unique to this process and call; :func:`retire` it when done."""
    holder = f"{socket.gethostname()}:{os.getpid()}:{kind}-{uuid.uuid4().hex[:8]}"
    _LIVE_HERE.add(holder)
    return holder


def retire(holder: str) -> None:
    _LIVE_HERE.discard(holder)


def known_dead(holder: str) -> bool:
    """Whether ``holder`` ran on this host in a process that no longer runs it.

    Only a holder of this host can be judged; any other is alive until its lease expires.
    """
    host, _, rest = holder.partition(":")
    pid_text, _, _ = rest.partition(":")
    if host != socket.gethostname() or not pid_text.isdigit():
        return False
    pid = int(pid_text)
    if pid == os.getpid():
        return holder not in _LIVE_HERE
    return not pid_alive(pid)
