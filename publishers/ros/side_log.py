"""The ROS side's log (``ros-side.log``): what its process writes on stderr, bounded on disk.

The bridge reads the ROS side's stderr through a pipe, line by line, into :class:`BoundedLog`: the
current file up to its bound, then it becomes ``ros-side.log.1`` (replacing the one before) and a
new one begins, so a ROS side that warns for weeks, or leaves a traceback at every restart, keeps
at most twice the bound on the robot's disk. Both files are 0600. The reader waits for nothing but
the file: a line it cannot write (a full disk) is dropped and counted, and the ROS side never
blocks on a full pipe.

Written here rather than with ``logging.handlers.RotatingFileHandler``: that one formats log
records (these are another process's raw bytes, partial lines included), and the files it makes
take the process's umask, where these must be 0600 from their first byte.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO, BinaryIO

from fleetbus.private_files import private_file

log = logging.getLogger("fleetbus.ros")

#: The most of one line read at once: a line without an end is written in pieces, never held whole.
PIECE_MOST = 64 * 1024


class BoundedLog:
    """Thread-safe: ``path`` up to ``max_bytes``, and the file before it, ``path.1``."""

    def __init__(self, path: Path, max_bytes: int) -> None:
        self.path = path
        self.older = path.with_name(path.name + ".1")
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self._file: BinaryIO | None = None
        self._size = 0

    def open(self) -> None:
        """Make the file (0600) if it is missing; raises OSError."""
        with self._lock:
            self._opened()

    def write(self, data: bytes) -> None:
        """Append ``data`` (its last ``max_bytes`` at most), turning the file over first when it
        would grow past the bound; raises OSError (the next write measures the file again)."""
        data = data[-self.max_bytes :]
        with self._lock:
            try:
                file = self._opened()
                if self._size and self._size + len(data) > self.max_bytes:
                    file = self._turned_over()
                file.write(data)
                self._size += len(data)
            except OSError:
                self._close()
                raise

    def close(self) -> None:
        with self._lock:
            self._close()

    def _opened(self) -> BinaryIO:
        if self._file is not None:
            return self._file
        descriptor = os.open(private_file(self.path), os.O_WRONLY | os.O_APPEND)
        self._file = os.fdopen(descriptor, "ab", buffering=0)
        self._size = os.fstat(descriptor).st_size
        if self._size > self.max_bytes:  # an older bridge's unbounded log, or a lowered bound
            return self._turned_over()
        return self._file

    def _turned_over(self) -> BinaryIO:
        """The file becomes the older one (the one before is gone) and a new one begins."""
        self._close()
        os.replace(self.path, self.older)
        _keep_tail(self.older, self.max_bytes)
        return self._opened()

    def _close(self) -> None:
        if self._file is not None:
            file, self._file = self._file, None
            file.close()


def _keep_tail(path: Path, max_bytes: int) -> None:
    """Cut ``path`` to its last ``max_bytes``, when it is larger."""
    with path.open("r+b") as file:
        if file.seek(0, os.SEEK_END) <= max_bytes:
            return
        file.seek(-max_bytes, os.SEEK_END)
        tail = file.read()
        file.seek(0)
        file.write(tail)
        file.truncate()


def copy_lines(stream: IO[bytes], into: BoundedLog, dropped: Callable[[], None]) -> None:
    """Every line of ``stream`` into ``into`` until the stream ends; ``dropped`` is called for each
    line (or piece of one) that could not be written."""
    failing = False
    while line := stream.readline(min(PIECE_MOST, into.max_bytes)):
        try:
            into.write(line)
        except OSError as error:
            dropped()
            if not failing:
                log.warning("cannot write %s (%s): its lines are dropped and counted", into.path, error)
            failing = True
            continue
        if failing:
            log.info("%s is written again", into.path)
        failing = False
