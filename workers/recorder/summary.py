"""One line of what a recorded message says, for the tables of the command line and the console."""

from __future__ import annotations

import json
from typing import Any

from fleetbus.schemas.ros import ROS_TYPE
from fleetbus.workers.recorder.capture import DEAD_LETTER, NOTIFICATION, refusal
from fleetbus.workers.recorder.queries import EVENT_TYPES
from fleetbus.workers.store.recordings import RecordedMessage


def shorten(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def compact(value: Any) -> str:
    """JSON on one line, without spaces."""
    return json.dumps(value, separators=(",", ":"), ensure_ascii=False, default=str)


def summarize(record: RecordedMessage, width: int) -> str:
    """One line of what a recorded message says, for tables."""
    doc = record.document
    if record.type == DEAD_LETTER:
        reason, detail = refusal(record) or ("by the broker", "")
        text = f"refused ({reason}): {detail}"
    elif not record.body_kept:
        text = f"({record.size} bytes, not kept)"
    elif record.raw is not None:
        text = f"({record.size} bytes, not JSON)"
    elif record.type == NOTIFICATION and isinstance(doc, dict) and isinstance(doc.get("event"), dict):
        event = doc["event"]
        extra = {k: v for k, v in doc.items() if k in ("hazard_id", "map_version", "late") and v}
        text = f"{doc.get('topic')}: {event.get('robot_id')} seq {event.get('seq')} "
        text += compact(extra) if extra else ""
    elif record.type == ROS_TYPE and isinstance(doc, dict):
        text = f"{doc.get('topic')} {doc.get('ros_type')} {compact(doc.get('fields'))}"
    elif isinstance(doc, dict) and record.type in EVENT_TYPES and "body" in doc:
        text = compact(doc["body"])
    else:
        text = compact(doc)
    return shorten(text.strip(), width)
