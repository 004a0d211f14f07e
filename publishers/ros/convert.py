"""ROS messages (as the ROS side's documents) to fleetbus event bodies, and back for notifications."""

from __future__ import annotations

import base64
import math
from datetime import datetime, timezone
from typing import Any

from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.ros import BYTES_KEY, RAW_KEY, TRUNCATED_KEY

#: map_server's thresholds: an occupancy at or above 65 % is occupied, at or below 19.6 % free.
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
FREE, UNKNOWN, OCCUPIED = 254, 205, 0


class ConversionError(ValueError):
    """A message that does not hold what its mapping rule needs."""


def at(document: dict[str, Any], path: str) -> Any:
    """The value at a dotted ``path`` (``pose.position.x``) of a message document."""
    value: Any = document
    for part in path.split("."):
        if not isinstance(value, dict) or part not in value:
            raise ConversionError(f"the message has no field {path!r}")
        value = value[part]
    return value


def find_pose(fields: dict[str, Any], path: str | None) -> dict[str, Any]:
    """A geometry_msgs/Pose document: at ``path``, else ``pose.pose`` (the ...WithCovariance
    types) or ``pose``."""
    candidates = [path] if path else ["pose.pose", "pose"]
    for candidate in candidates:
        try:
            value = at(fields, candidate)
        except ConversionError:
            continue
        if isinstance(value, dict) and "position" in value and "orientation" in value:
            return value
    raise ConversionError(f"the message holds no geometry_msgs/Pose at {' or '.join(candidates)}")


def fleetbus_pose(pose: dict[str, Any]) -> dict[str, Any]:
    q = pose["orientation"]
    return {
        "x": pose["position"]["x"],
        "y": pose["position"]["y"],
        "orientation": {"x": q["x"], "y": q["y"], "z": q["z"], "w": q["w"]},
    }


def localisation_body(fields: dict[str, Any], path: str | None) -> dict[str, Any]:
    return {"localised": True, "pose": fleetbus_pose(find_pose(fields, path))}


def hazard_body(
    fields: dict[str, Any],
    description_path: str | None,
    pose_path: str | None,
    last_pose: dict[str, Any] | None,
    frame_id: str,
    detected_at: datetime,
) -> dict[str, Any]:
    description = str(at(fields, description_path or "data"))
    if pose_path is not None:
        pose = fleetbus_pose(find_pose(fields, pose_path))
    elif last_pose is not None:
        pose = last_pose
    else:
        raise ConversionError("a hazard needs a pose: the rule names none and no pose was seen yet")
    return {
        "pose": pose,
        "frame_id": frame_id,
        "description": description,
        "detected_at": detected_at.isoformat(),
    }


def yaw(q: dict[str, Any]) -> float:
    return math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]), 1 - 2 * (q["y"] ** 2 + q["z"] ** 2))


def occupancy_grid_map(fields: dict[str, Any]) -> tuple[bytes, dict[str, Any]]:
    """A nav_msgs/OccupancyGrid as map_server saves it: the PGM image (top row first) and its fields."""
    info = fields["info"]
    width, height = int(info["width"]), int(info["height"])
    data = [v - 256 if v > 127 else v for v in byte_array(fields["data"])]  # int8: -1 is unknown
    if width < 1 or height < 1 or len(data) != width * height:
        raise ConversionError(f"an occupancy grid of {width}x{height} cells holds {len(data)} values")
    occupied, free = OCCUPIED_THRESH * 100, FREE_THRESH * 100
    pixels = bytes(
        UNKNOWN if v < 0 else OCCUPIED if v >= occupied else FREE if v <= free else UNKNOWN for v in data
    )
    rows = [pixels[row * width : (row + 1) * width] for row in range(height)]
    pgm = f"P5\n{width} {height}\n255\n".encode() + b"".join(reversed(rows))  # the grid's row 0 is the bottom
    origin = info["origin"]
    metadata = {
        "resolution": info["resolution"],
        "origin": (origin["position"]["x"], origin["position"]["y"], yaw(origin["orientation"])),
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
        "negate": 0,
    }
    return pgm, metadata


def ros_stamp(nanos: int | None) -> datetime | None:
    """A ROS time in nanoseconds since the epoch, in UTC to the microsecond (None for none)."""
    if not nanos:
        return None
    seconds, rest = divmod(nanos, 1_000_000_000)
    return datetime.fromtimestamp(seconds, timezone.utc).replace(microsecond=rest // 1000)


def byte_array(value: Any) -> bytes:
    """A ``uint8[]``/``int8[]`` field as the ROS side sends it (``{"_base64": ..., "length": n}``,
    or a large one read beside its line, ``{"_raw": b"..."}``)."""
    if isinstance(value, dict) and isinstance(value.get(RAW_KEY), bytes):
        return value[RAW_KEY]
    if isinstance(value, dict) and BYTES_KEY in value:
        return base64.b64decode(value[BYTES_KEY])
    if isinstance(value, dict) and value.get(TRUNCATED_KEY):
        raise ConversionError(f"an array of {value.get('length')} bytes was cut at the bridge's byte limit")
    if isinstance(value, list):
        return bytes(v & 0xFF for v in value)
    raise ConversionError(f"not a byte array: {str(value)[:80]}")


def ros_time(moment: datetime) -> dict[str, int]:
    seconds = moment.timestamp()
    return {"secs": int(seconds), "nsecs": round((seconds - int(seconds)) * 1e9) % 1_000_000_000}


def notification_messages(note: Notification, prefix: str) -> list[dict[str, Any]]:
    """What the ROS side publishes for a notification: its JSON on ``<prefix>/<topic>`` (std_msgs/String)
    and, for a hazard, its place on ``<prefix>/hazard_pose`` (geometry_msgs/PoseStamped)."""
    messages = [
        {
            "kind": "publish",
            "topic": f"{prefix}/{note.topic.value}",
            "type": "std_msgs/String",
            "fields": {"data": note.model_dump_json()},
        }
    ]
    body = note.event.body
    if note.topic.value == "hazard":
        pose = body.pose  # type: ignore[union-attr]
        messages.append(
            {
                "kind": "publish",
                "topic": f"{prefix}/hazard_pose",
                "type": "geometry_msgs/PoseStamped",
                "fields": {
                    "header": {"stamp": ros_time(body.detected_at), "frame_id": body.frame_id},  # type: ignore[union-attr]
                    "pose": {
                        "position": {"x": pose.x, "y": pose.y, "z": 0.0},
                        "orientation": pose.orientation.model_dump(),
                    },
                },
            }
        )
    return messages
