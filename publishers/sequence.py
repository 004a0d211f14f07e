"""The robot's sequence numbers: they only grow, also across restarts of the robot process.

The server keys every record by (robot, sequence number); a counter that restarted at zero after
a reboot would make new events look like reused numbers (the server dead-letters those as
``sequence-reused`` rather than dropping them, but they should not happen).

The counter itself lives in memory; what makes it survive a restart is the outbox, which knows
the highest number it ever held (:meth:`publishers.outbox.Outbox.next_seq`). Numbers handed out
for events that never reached the outbox (the process died in between) may be handed out again:
nobody outside the process saw them.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path


class SequenceCounter:
    def __init__(self, floor: int = 0) -> None:
        self._next = floor
        self._lock = threading.Lock()

    def peek(self) -> int:
        return self._next

    def reserve(self, count: int = 1) -> int:
        """Reserve ``count`` consecutive numbers and return the first."""
        with self._lock:
            first = self._next
            self._next += count
            return first

    def at_least(self, value: int) -> None:
        with self._lock:
            self._next = max(self._next, value)


def legacy_floor(path: Path) -> int:
    """The next number kept in ``state.json`` by clients before the outbox kept it; 0 without one."""
    try:
        doc = json.loads(path.read_text()).get("sequence", {}).get("1", {})
    except (FileNotFoundError, ValueError):
        return 0
    return int(doc.get("next", 0))
