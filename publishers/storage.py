"""A TinyDB storage that survives the robot process being killed at any instant.

TinyDB's default ``JSONStorage`` truncates its file and writes it again in place, without
fsync: a robot killed in the middle of a write finds a half-written file that TinyDB cannot
load. This storage writes a temporary file, fsyncs it, renames it over the old one and fsyncs
the folder, so the file always holds either the old or the new content, on disk.

It also keeps what it last wrote in memory: the robot process is the only writer (the client
holds a lock on its state folder), so reading the file back on every operation is wasted work.

The robot's personal database is its own: folders 0700, files 0600.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from tinydb.storages import Storage


def own_folder(path: Path) -> Path:
    """``path`` and the folders missing above it, made 0700 (only the robot's user may enter)."""
    missing = []
    folder = path
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for each in reversed(missing):
        each.mkdir(mode=0o700, exist_ok=True)
    return path


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path: Path, data: bytes, durable: bool = True) -> None:
    """Replace ``path`` with ``data`` so that a crash leaves the old or the new file, never a mix."""
    temporary = path.with_name(f".{path.name}.tmp")
    with os.fdopen(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "wb") as handle:
        handle.write(data)
        if durable:
            handle.flush()
            os.fsync(handle.fileno())
    os.replace(temporary, path)
    if durable:
        fsync_dir(path.parent)


class AtomicJSONStorage(Storage):
    """``TinyDB(path, storage=AtomicJSONStorage)``; ``durable=False`` skips fsync (tests, benchmarks)."""

    def __init__(self, path: str | Path, durable: bool = True) -> None:
        self.path = Path(path)
        own_folder(self.path.parent)
        self.durable = durable
        self._cache: dict[str, dict[str, Any]] | None = None

    def read(self) -> dict[str, dict[str, Any]] | None:
        if self._cache is not None:
            return self._cache
        try:
            text = self.path.read_bytes()
        except FileNotFoundError:
            return None
        if not text.strip():
            return None
        self._cache = json.loads(text)
        return self._cache

    def write(self, data: dict[str, dict[str, Any]]) -> None:
        # TinyDB mutates what read() returned before it calls write(); if the write fails, the
        # next read must come from the file, not from that mutated copy.
        self._cache = None
        write_atomically(self.path, json.dumps(data, separators=(",", ":")).encode(), self.durable)
        self._cache = data

    def close(self) -> None:
        self._cache = None
