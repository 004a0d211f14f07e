"""What Foxglove can draw of a recorded fleetbus message: the map as a grid, poses, hazards.

Each function takes a record's document (a fleetbus event envelope) and returns the Foxglove
message it makes, or None when the record has nothing to draw (a chunked map, a localisation
without a pose, a body that does not follow the schema).
"""

from __future__ import annotations

import base64
import math
from collections.abc import Callable
from datetime import datetime
from typing import Any

from fleetbus.schemas import foxglove as fg
from fleetbus.schemas.pgm import read_pgm_header
from fleetbus.schemas.routing import EventType

MAP_FRAME = "map"
HAZARD_COLOUR = fg.Color(r=1.0, g=0.25, b=0.1, a=0.9)
HAZARD_SIZE = 0.5
"""Metres across the sphere drawn at a hazard."""


def _pose(pose: Any) -> fg.Pose | None:
    if not isinstance(pose, dict) or not all(isinstance(pose.get(k), (int, float)) for k in ("x", "y")):
        return None
    q = pose.get("orientation") if isinstance(pose.get("orientation"), dict) else {}
    return fg.Pose(
        position=fg.Vector3(x=pose["x"], y=pose["y"]),
        orientation=fg.Quaternion(**{k: float(q[k]) for k in ("x", "y", "z", "w") if k in q}),
    )


def _body(document: Any) -> dict[str, Any]:
    body = document.get("body") if isinstance(document, dict) else None
    return body if isinstance(body, dict) else {}


def pose_in_frame(document: Any, at: datetime) -> fg.PoseInFrame | None:
    """A status's or a localisation's pose, in the map frame."""
    pose = _pose(_body(document).get("pose"))
    return None if pose is None else fg.PoseInFrame(timestamp=fg.Time.of(at), frame_id=MAP_FRAME, pose=pose)


def hazard_scene(document: Any, at: datetime, key: str) -> fg.SceneUpdate | None:
    """A hazard as a sphere with its description above it; it stays until the end of the file."""
    body = _body(document)
    pose = _pose(body.get("pose"))
    if pose is None:
        return None
    description = str(body.get("description", "hazard"))
    label_at = fg.Pose(position=fg.Vector3(x=pose.position.x, y=pose.position.y, z=HAZARD_SIZE))
    entity = fg.SceneEntity(
        timestamp=fg.Time.of(at),
        frame_id=str(body.get("frame_id") or MAP_FRAME),
        id=str(document.get("message_id") or key),
        metadata=[fg.KeyValuePair(key="description", value=description)],
        spheres=[
            fg.SpherePrimitive(
                pose=pose,
                size=fg.Vector3(x=HAZARD_SIZE, y=HAZARD_SIZE, z=HAZARD_SIZE),
                color=HAZARD_COLOUR,
            )
        ],
        texts=[fg.TextPrimitive(pose=label_at, color=HAZARD_COLOUR, text=description)],
    )
    return fg.SceneUpdate(entities=[entity])


def map_grid(document: Any, at: datetime) -> fg.Grid | None:
    """An inline binary map image (8-bit PGM) as a grid: one ``uint8`` cell per pixel, 0 free to
    255 occupied (the image inverted unless its metadata says ``negate``), row 0 at the origin."""
    body = _body(document)
    metadata = body.get("metadata")
    try:
        pgm = base64.b64decode(body["pgm"], validate=True)
        header = read_pgm_header(pgm)
        resolution = float(metadata["resolution"])
        x, y, yaw = (float(v) for v in metadata["origin"])
    except (KeyError, TypeError, ValueError):
        return None
    if header.magic != "P5" or header.maxval > 255 or header.expected_size != len(pgm):
        return None
    pixels = pgm[header.length :]
    if not metadata.get("negate"):
        pixels = pixels.translate(bytes(range(255, -1, -1)))
    width = header.width
    rows = [pixels[i : i + width] for i in range(0, len(pixels), width)]
    return fg.Grid(
        timestamp=fg.Time.of(at),
        frame_id=MAP_FRAME,
        pose=fg.Pose(
            position=fg.Vector3(x=x, y=y),
            orientation=fg.Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
        ),
        column_count=width,
        cell_size=fg.Vector2(x=resolution, y=resolution),
        row_stride=width,
        cell_stride=1,
        fields=[fg.PackedElementField(name="occupancy", offset=0, type=fg.NumericType.UINT8)],
        data=base64.b64encode(b"".join(reversed(rows))).decode(),
    )


View = Callable[[Any, datetime, str], fg.FoxgloveModel | None]

#: Per fleetbus type: the Foxglove view it gets, its topic's last segment and the view's schema.
VIEWS: dict[str, tuple[str, type[fg.FoxgloveModel], View]] = {
    EventType.MAP.value: ("map/grid", fg.Grid, lambda doc, at, key: map_grid(doc, at)),
    EventType.STATUS.value: ("status/pose", fg.PoseInFrame, lambda doc, at, key: pose_in_frame(doc, at)),
    EventType.LOCALISATION.value: (
        "localisation/pose",
        fg.PoseInFrame,
        lambda doc, at, key: pose_in_frame(doc, at),
    ),
    EventType.HAZARD.value: ("hazards", fg.SceneUpdate, hazard_scene),
}
