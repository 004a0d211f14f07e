"""What the ROS bridge holds in memory between ROS and the outbox: a queue bounded by its count of
messages and by their bytes, on both sides of the pipe (the ROS side holds the raw messages, the
bridge the parsed ones).

A count alone does not bound memory: 10,000 camera images are gigabytes. What does not fit is
refused, and the caller counts it as dropped. One message larger than the whole byte bound is
taken when nothing else is held, so that a large image still passes when the bridge keeps up.

It imports nothing but the standard library: ``ros_side.py`` runs on the interpreter ROS is
installed for and imports it from its own folder.
"""

from __future__ import annotations

import queue
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class HeldQueue(Generic[T]):
    def __init__(self, most_messages: int, most_bytes: int) -> None:
        self._queue: queue.Queue[tuple[T, int]] = queue.Queue(most_messages)
        self._most_bytes = most_bytes
        self._bytes = 0
        self._lock = threading.Lock()

    @property
    def held_bytes(self) -> int:
        return self._bytes

    def offer(self, item: T, size: int) -> bool:
        """Hold ``item`` (``size`` bytes) unless that passes a bound; False when refused."""
        with self._lock:
            if self._bytes and self._bytes + size > self._most_bytes:
                return False
            try:
                self._queue.put_nowait((item, size))
            except queue.Full:
                return False
            self._bytes += size
        return True

    def get(self, timeout: float) -> T:
        """The oldest message held; ``queue.Empty`` when none comes within ``timeout``."""
        item, size = self._queue.get(timeout=timeout)
        with self._lock:
            self._bytes -= size
        return item
