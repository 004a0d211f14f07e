"""Bodies of the events robots publish. Field names follow ROS conventions where one exists."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import (
    AwareDatetime,
    Base64Bytes,
    BaseModel,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

PGM_MAGIC = (b"P5", b"P2")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Quaternion(Strict):
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


class Pose(Strict):
    """A 2-D position in the map frame with a 3-D orientation, as ``geometry_msgs/Pose``."""

    x: float
    y: float
    orientation: Quaternion = Quaternion()


class HazardDetected(Strict):
    pose: Pose
    frame_id: str = Field(default="map", min_length=1, max_length=64)
    description: Annotated[str, Field(min_length=1, max_length=512)]
    detected_at: AwareDatetime

    @field_validator("description")
    @classmethod
    def _not_blank(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("description must not be blank")
        return value


class MapMetadata(Strict):
    """The fields of a ``map_server`` YAML file."""

    image: str = "map.pgm"
    resolution: float = Field(gt=0, description="metres per pixel")
    origin: tuple[float, float, float] = Field(description="x, y, yaw of the lower-left pixel")
    occupied_thresh: float = Field(ge=0, le=1)
    free_thresh: float = Field(ge=0, le=1)
    negate: Literal[0, 1] = 0

    @model_validator(mode="after")
    def _thresholds_ordered(self) -> MapMetadata:
        if self.free_thresh >= self.occupied_thresh:
            raise ValueError("free_thresh must be below occupied_thresh")
        return self


class MapUpdate(Strict):
    pgm: Base64Bytes = Field(description="the PGM image, base64 in JSON")
    metadata: MapMetadata
    created_at: AwareDatetime

    @field_validator("pgm")
    @classmethod
    def _is_pgm(cls, value: bytes) -> bytes:
        if not value.startswith(PGM_MAGIC):
            raise ValueError("pgm is not a PGM image (no P5 or P2 header)")
        return value


class RobotStatus(Strict):
    battery_percent: float = Field(ge=0, le=100)
    pose: Pose
    current_waypoint: str | None = Field(default=None, max_length=128)
    processing_rate_hz: float = Field(ge=0)


class LocalisationState(Strict):
    localised: bool
    pose: Pose | None = None


class BeaconSighting(Strict):
    beacon_id: str = Field(min_length=1, max_length=64)
    rssi: int = Field(ge=-127, le=20, description="dBm")
    pose: Pose | None = Field(default=None, description="where the robot was when it heard the beacon")


class BehaviourOutcome(Strict):
    name: str = Field(min_length=1, max_length=128)
    success: bool
    duration_s: float = Field(ge=0)
    error: str | None = Field(default=None, max_length=2048)
    started_at: datetime | None = None
