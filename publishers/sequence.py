"""The robot's sequence numbers: 0, 1, 2, ... within the epoch its client minted at the start.

The server keys every event by (robot, epoch, seq). Each start of a client mints a new epoch
(:func:`fleetbus.schemas.envelope.new_epoch`) and counts from 0 in it, so nothing has to survive a restart
for the numbers to stay unique: a robot whose personal database was lost, or a spare running
with the same account, starts an epoch of its own. Events waiting in the outbox keep the epoch
and number they were built with, so sending one again after a restart is an exact duplicate.
"""

from __future__ import annotations

import threading


class SequenceCounter:
    def __init__(self) -> None:
        self._next = 0
        self._lock = threading.Lock()

    def reserve(self, count: int = 1) -> int:
        """Reserve ``count`` consecutive numbers and return the first."""
        with self._lock:
            first = self._next
            self._next += count
            return first
