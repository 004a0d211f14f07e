"""One process at a time per robot: its personal database is not shared."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from fleetbus.publishers.errors import PublisherError
from fleetbus.publishers.storage import own_folder


class RobotStateInUse(PublisherError, RuntimeError):
    """Another process holds this robot's personal database (a RuntimeError too, as it was)."""


class StateLock:
    """An exclusive ``flock`` on ``<robot state>/lock``, released when the process ends (even by a kill)."""

    def __init__(self, folder: Path) -> None:
        own_folder(folder)
        self.path = folder / "lock"
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise RobotStateInUse(
                f"{self.path.parent} is in use by pid {holder}: one process per robot at a time"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
