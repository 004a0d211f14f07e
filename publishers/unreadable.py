"""Outbox files found unreadable when the outbox opens: checked, and set aside beside themselves.

A robot whose outbox holds a file it cannot parse (a segment cut short by a failing disk, a
``meta.json`` edited by hand) must still start: the file is renamed with
:data:`UNREADABLE_SUFFIX` and the time, never deleted, so that someone can look at it later.
"""

from __future__ import annotations

import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from fleetbus.publishers.storage import fsync_dir

UNREADABLE_SUFFIX = ".unreadable-"
#: What the outbox's dropped counts call the files set aside (status events' ``outbox_dropped``).
UNREADABLE_COUNT = "unreadable-file"
#: What parsing a file's content fails with (reading it, an OSError, is another matter: a file
#: the robot may not read now is not to be set aside).
UNREADABLE = (ValueError, KeyError, TypeError, AttributeError)


def set_aside(path: Path) -> Path:
    """Rename ``path`` to ``<name>.unreadable-<UTC time>`` in its folder; the new path."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S%fZ")
    target = path.with_name(f"{path.name}{UNREADABLE_SUFFIX}{stamp}")
    os.replace(path, target)
    fsync_dir(path.parent)
    return target


def check_tables(data: Any) -> None:
    """Raise ValueError unless ``data`` is what a TinyDB file holds: tables of documents by id."""
    if data is None:
        return
    if not isinstance(data, dict) or not all(
        isinstance(table, dict) and all(isinstance(doc, dict) for doc in table.values())
        for table in data.values()
    ):
        raise ValueError("not tables of documents")


def check_counters(data: Any) -> None:
    """Raise ValueError unless ``data`` holds the outbox's counters as the outbox writes them."""
    check_tables(data)
    for doc in (data or {}).get("counters", {}).values():
        for counts in doc.values():
            if not isinstance(counts, dict) or not all(
                isinstance(name, str) and isinstance(n, int) for name, n in counts.items()
            ):
                raise ValueError(f"counts that are not numbers by type: {counts!r}")


def check_event(doc: Any) -> None:
    """Raise (one of :data:`UNREADABLE`) unless ``doc`` is a waiting event as the outbox wrote it."""
    for name, kind in (("epoch", str), ("seq", int), ("type", str), ("message_id", str), ("sent_at", str)):
        if not isinstance(doc[name], kind):
            raise TypeError(f"{name} is not a {kind.__name__}: {doc[name]!r}")
    datetime.fromisoformat(doc["sent_at"])
    if not isinstance(doc.get("body", doc.get("blob")), str):
        raise TypeError("neither a body nor a body file")
