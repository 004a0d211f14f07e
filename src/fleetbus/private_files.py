"""What fleetbus keeps in its data folder is its owner's only, as a database server keeps its data.

The store holds password hashes and sealed broker passwords, the recording every message, the
``accounts`` and ``api`` folders secrets, the ``tls`` folder keys: every folder fleetbus makes is
0700 and every file 0600. Writers make their files through :func:`private_file` (or with mode
0600 themselves); the long-running processes (worker, recorder, API, site, broker node) also run
under :data:`OWNER_ONLY` as their umask, so that what a library writes for them (SQLite's WAL,
RabbitMQ's database and logs) is owner-only too, as PostgreSQL's postmaster sets its own.
"""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path

FOLDER_MODE = 0o700
FILE_MODE = 0o600
#: The umask of a process that writes only its owner's data.
OWNER_ONLY = 0o077


def private_dir(path: Path) -> Path:
    """``path`` and every missing folder above it, made 0700; an existing ``path`` that others
    may read is narrowed to 0700 (the folders above it that existed are left as they are)."""
    missing: list[Path] = []
    folder = path
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for each in reversed(missing):
        with contextlib.suppress(FileExistsError):  # another process made it meanwhile
            each.mkdir(mode=FOLDER_MODE)
    _narrow(path, FOLDER_MODE)
    return path


def private_file(path: Path) -> Path:
    """``path`` exists and is 0600 (made empty if missing, in a 0700 folder), before anything is
    written to it: nobody else can open it between its creation and its first write."""
    private_dir(path.parent)
    with contextlib.suppress(FileExistsError):
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE))
    _narrow(path, FILE_MODE)
    return path


def owner_only_umask() -> int:
    """Make this process's umask :data:`OWNER_ONLY`; the umask it had."""
    return os.umask(OWNER_ONLY)


def _narrow(path: Path, mode: int) -> None:
    """``path`` to ``mode`` when it is ours and others may use it."""
    info = path.stat()
    if info.st_uid == os.geteuid() and stat.S_IMODE(info.st_mode) & OWNER_ONLY:
        path.chmod(mode)
