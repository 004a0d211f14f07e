"""The robot's sequence numbers, kept in its personal TinyDB database so they only grow.

The server keys every record by (robot, sequence number); a counter that restarted at zero after
a reboot would make new events look like duplicates of old ones (the server dead-letters those
as ``sequence-reused`` rather than dropping them, but they should not happen).
"""

from __future__ import annotations

import threading
from pathlib import Path

from tinydb import TinyDB
from tinydb.table import Document

from publishers.storage import AtomicJSONStorage


class SequenceCounter:
    def __init__(self, path: Path, durable: bool = True) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._db = TinyDB(path, storage=AtomicJSONStorage, durable=durable)
        self._table = self._db.table("sequence")
        self._lock = threading.Lock()

    def peek(self) -> int:
        doc = self._table.get(doc_id=1)
        return int(doc["next"]) if doc else 0

    def reserve(self, count: int = 1) -> int:
        """Reserve ``count`` consecutive numbers and return the first; persisted before returning."""
        with self._lock:
            first = self.peek()
            self._table.upsert(Document({"next": first + count}, doc_id=1))
            return first

    def at_least(self, value: int) -> None:
        """Never hand out a number below ``value`` (events found waiting in the outbox use them)."""
        with self._lock:
            if self.peek() < value:
                self._table.upsert(Document({"next": value}, doc_id=1))

    def close(self) -> None:
        self._db.close()
