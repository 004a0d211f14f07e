"""Per-topic counts of what the bridge recorded, mapped and dropped (with why): never a silent drop."""

from __future__ import annotations

import json
import os
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleetbus.publishers.ros.parts import Parts
from fleetbus.publishers.storage import write_atomically


class DropReason:
    ROS_QUEUE = "ros-queue"
    """The ROS side's queue was full (the bridge read its pipe too slowly)."""
    BRIDGE_QUEUE = "bridge-queue"
    """The bridge's queue between the pipe and the outbox was full (``FLEETBUS_ROS_QUEUE``)."""
    RATE = "rate"
    """Above the topic's maximum rate (``FLEETBUS_ROS_MAX_RATE_HZ``)."""
    OUTBOX_FULL = "outbox-full"
    """The robot's outbox held as many events as it may keep while the broker was away."""
    UNREADABLE = "unreadable"
    """The ROS side could not read the message (nothing of it is recorded)."""
    NOT_MAPPED = "not-mapped"
    """The message is recorded, but did not hold what its mapping rule needs: no event was made of it."""
    WRITE_FAILED = "write-failed"
    """The outbox could not be written (its error is in the status's parts) until the bridge stopped."""
    ROS_SIDE_GONE = "ros-side-gone"
    """A notification or command for ROS came while the ROS side was down (restarting)."""
    LOG_FAILED = "log-write-failed"
    """A line of the ROS side's log (its stderr) could not be written to ``ros-side.log`` (a full disk)."""


@dataclass
class Counters:
    """Thread-safe counts, per topic; :meth:`snapshot` is what the status line and file show."""

    started: float = field(default_factory=time.time)
    recorded: Counter[str] = field(default_factory=Counter)
    mapped: Counter[str] = field(default_factory=Counter)
    over_bound: Counter[str] = field(default_factory=Counter)
    """Messages recorded with a byte array over ``FLEETBUS_ROS_BLOB_MAX_BYTES``: only described."""
    blobs: Counter[str] = field(default_factory=Counter)
    """Byte arrays sent whole as ``ros_chunk`` events."""
    dropped: dict[str, Counter[str]] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    notifications: int = 0
    ros_side: str = "starting"
    master: dict[str, Any] = field(default_factory=lambda: {"state": "unknown"})
    """How the ROS master answers: ``state`` (``running``, ``unreachable``), ``detail``, ``since``,
    ``failures`` (tries in a row that failed), ``retry_in``, ``restarts`` (seen since the start)."""
    parts: Parts = field(default_factory=Parts)
    """The bridge's threads and its ROS side: each ``running`` or ``restarting`` (after a failure)."""
    broker: dict[str, Any] = field(default_factory=dict)
    """The robot client's sender (outbox to broker; it retries by itself): ``connected``, ``last_error``."""
    ended: str | None = None
    """Why the bridge itself ended, when it could not go on (its exit code is not 0 then)."""
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _write_lock: threading.Lock = field(default_factory=threading.Lock)
    """Held from a write's snapshot to its rename: the file never goes back to an older state."""

    def drop(self, topic: str, reason: str, count: int = 1) -> None:
        with self._lock:
            self.dropped.setdefault(topic, Counter())[reason] += count

    def master_said(self, state: str, detail: str, uri: str, retry_in: float | None, restarted: bool) -> None:
        """What the ROS side reported of the master (every failed try, and every change)."""
        with self._lock:
            before = self.master
            changed = before.get("state") != state
            self.master = {
                "state": state,
                "uri": uri,
                "detail": detail,
                "since": time.time() if changed else before.get("since", time.time()),
                "failures": 0 if state == "running" else before.get("failures", 0) + 1,
                "retry_in": retry_in,
                "restarts": before.get("restarts", 0) + int(restarted),
            }

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            named = (self.types, self.recorded, self.mapped, self.dropped, self.over_bound)
            topics = sorted(set().union(*named))
            return {
                "pid": os.getpid(),
                "started": self.started,
                "updated": time.time(),
                "ros_side": self.ros_side,
                "master": dict(self.master),
                "parts": self.parts.snapshot(),
                "broker": dict(self.broker),
                **({"ended": self.ended} if self.ended else {}),
                "notifications_published": self.notifications,
                "topics": {
                    topic: {
                        "type": self.types.get(topic),
                        "recorded": self.recorded[topic],
                        "mapped": self.mapped[topic],
                        "blobs": self.blobs[topic],
                        "over_bound": self.over_bound[topic],
                        "dropped": dict(self.dropped.get(topic, {})),
                    }
                    for topic in topics
                },
            }

    def status_line(self) -> str:
        snap = self.snapshot()
        recorded = sum(t["recorded"] for t in snap["topics"].values())
        mapped = sum(t["mapped"] for t in snap["topics"].values())
        drops = [
            f"{topic} {sum(t['dropped'].values())} ({', '.join(f'{r} {n}' for r, n in t['dropped'].items())})"
            for topic, t in snap["topics"].items()
            if t["dropped"]
        ]
        over = [f"{topic} {t['over_bound']}" for topic, t in snap["topics"].items() if t["over_bound"]]
        master = snap["master"]
        said = f"master {master['state']}"
        if master["state"] == "unreachable":
            said += f" ({master['failures']} tries, next in {master['retry_in']:.0f} s: {master['detail']})"
        failing = [
            f"{name} {part['state']} ({part['restarts']} restarts; last: {part['last_failure']})"
            for name, part in snap["parts"].items()
            if part.get("last_failure")
        ]
        return (
            (f"parts that failed: {'; '.join(failing)}; " if failing else "")
            + f"{said}; {len(snap['topics'])} topics, {recorded} recorded, {mapped} as events, "
            f"dropped: {'; '.join(drops) if drops else 'none'}"
            + (f"; byte arrays over the bound, described only: {'; '.join(over)}" if over else "")
        )

    def write(self, path: Path) -> None:
        """The snapshot as JSON, replaced atomically (``fleetbus ros status`` reads it). The
        bridge's threads write it at once (the master's reader, the status ticker): one at a time,
        snapshot to rename, or an older snapshot could land after a newer one and stay."""
        with self._write_lock:
            text = json.dumps(self.snapshot(), indent=1)
            write_atomically(path, text.encode(), durable=False)  # 0600, as the robot's other files


class RateLimit:
    """At most ``max_hz`` messages a second per topic (0: no limit): a message that comes sooner
    than ``1 / max_hz`` after the last one taken is dropped."""

    def __init__(self, max_hz: float) -> None:
        self._interval = 1.0 / max_hz if max_hz > 0 else 0.0
        self._last: dict[str, float] = {}

    def allows(self, topic: str, now: float) -> bool:
        if not self._interval:
            return True
        last = self._last.get(topic)
        if last is not None and now - last < self._interval:
            return False
        self._last[topic] = now
        return True
