"""The few Foxglove message schemas an MCAP export uses, as pydantic models.

Foxglove recognises a JSON channel by its schema's name (``foxglove.Grid``) and reads the fields
its schema defines; these models declare that layout for the subset fleetbus writes. They follow
Foxglove's published schemas (https://github.com/foxglove/schemas, MIT licence; the field layout
of its ``schemas/jsonschema`` folder as of November 2026: ``Grid``, ``PoseInFrame``,
``SceneUpdate``). No file of that repository is copied: the JSON Schemas written into an export
are generated from these models, which declare only the fields fleetbus fills.
"""

from __future__ import annotations

from datetime import datetime
from enum import IntEnum

from pydantic import BaseModel, ConfigDict, Field

FOXGLOVE_SCHEMAS_SOURCE = "https://github.com/foxglove/schemas (MIT)"


class FoxgloveModel(BaseModel):
    """A Foxglove message; its schema name is its title."""

    model_config = ConfigDict(frozen=True)


class Time(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="time")
    sec: int = Field(ge=0)
    nsec: int = Field(ge=0, le=999_999_999)

    @classmethod
    def of(cls, moment: datetime) -> Time:
        ns = round(moment.timestamp() * 1_000_000) * 1000
        return cls(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


class Duration(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="duration")
    sec: int = 0
    nsec: int = Field(default=0, ge=0, le=999_999_999)


class Vector2(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.Vector2")
    x: float
    y: float


class Vector3(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.Vector3")
    x: float
    y: float
    z: float = 0.0


class Quaternion(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.Quaternion")
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.Pose")
    position: Vector3
    orientation: Quaternion = Quaternion()


class Color(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.Color")
    r: float
    g: float
    b: float
    a: float = 1.0


class NumericType(IntEnum):
    UINT8 = 1


class PackedElementField(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.PackedElementField")
    name: str
    offset: int = Field(ge=0)
    type: NumericType


class Grid(FoxgloveModel):
    """A 2-D grid of cells; fleetbus writes a map as one ``uint8`` field, 0 free to 255 occupied."""

    model_config = ConfigDict(frozen=True, title="foxglove.Grid")
    timestamp: Time
    frame_id: str
    pose: Pose = Field(description="the grid's corner (cell 0, 0) in the frame")
    column_count: int = Field(ge=0)
    cell_size: Vector2
    row_stride: int = Field(ge=0)
    cell_stride: int = Field(ge=0)
    fields: list[PackedElementField]
    data: str = Field(json_schema_extra={"contentEncoding": "base64"})


class PoseInFrame(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.PoseInFrame")
    timestamp: Time
    frame_id: str
    pose: Pose


class KeyValuePair(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.KeyValuePair")
    key: str
    value: str


class SpherePrimitive(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.SpherePrimitive")
    pose: Pose
    size: Vector3
    color: Color


class TextPrimitive(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.TextPrimitive")
    pose: Pose
    billboard: bool = True
    font_size: float = 12.0
    scale_invariant: bool = True
    color: Color
    text: str


class SceneEntity(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.SceneEntity")
    timestamp: Time
    frame_id: str
    id: str
    lifetime: Duration = Duration()
    frame_locked: bool = False
    metadata: list[KeyValuePair] = []
    spheres: list[SpherePrimitive] = []
    texts: list[TextPrimitive] = []


class SceneUpdate(FoxgloveModel):
    model_config = ConfigDict(frozen=True, title="foxglove.SceneUpdate")
    deletions: list[dict[str, object]] = []
    entities: list[SceneEntity]
