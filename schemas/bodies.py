"""Bodies of the events robots publish. Field names follow ROS conventions where one exists."""

from __future__ import annotations

import uuid
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

from fleetbus.schemas.pgm import check_pgm

#: The largest integer an event may carry: the stores' integers are 64-bit (SQLite's INTEGER,
#: MongoDB's int64), so a larger one is refused by the schema, naming its field, not by the store.
INT64_MAX = 2**63 - 1


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


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
    description: Annotated[
        str,
        # the pattern says in the published schema what the validator below enforces, with its message
        Field(min_length=1, max_length=512, json_schema_extra={"pattern": r"\S", "description": "not blank"}),
    ]
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


#: Largest map image sent inside its ``map`` event; larger ones travel as ``map_chunk`` events.
MAP_INLINE_BYTES = 256 * 1024
#: Bytes per chunk event (``map_chunk``, ``ros_chunk``): about 700 KB as base64, below the broker's
#: message limit. Whatever is too large for one event travels as chunks of this size, in order,
#: before the event that names them.
CHUNK_BYTES = 512 * 1024
MAP_CHUNK_BYTES = CHUNK_BYTES


def chunk_count(size: int) -> int:
    """How many chunks of :data:`CHUNK_BYTES` carry ``size`` bytes (at least one)."""
    return max(1, (size + CHUNK_BYTES - 1) // CHUNK_BYTES)


def split_chunks(data: bytes) -> list[bytes]:
    """``data`` in the pieces its chunk events carry, in order."""
    return [data[i * CHUNK_BYTES : (i + 1) * CHUNK_BYTES] for i in range(chunk_count(len(data)))]


class ChunkedImage(Strict):
    """A map image sent ahead as ``map_chunk`` events with this ``map_id``."""

    map_id: uuid.UUID
    size: int = Field(gt=0, le=INT64_MAX, description="bytes of the whole PGM file")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    chunks: int = Field(ge=1, le=INT64_MAX)


class MapUpdate(Strict):
    """A new map: the PGM image (inline when small, else by reference to its chunks) and its YAML fields."""

    pgm: Base64Bytes | None = Field(
        default=None,
        description="the PGM image, base64 in JSON: a small map, of at most 256 KiB (262,144 bytes) "
        "before base64",
        json_schema_extra={"maxLength": 4 * -(-MAP_INLINE_BYTES // 3)},
    )
    image: ChunkedImage | None = Field(default=None, description="the PGM image sent as map_chunk events")
    metadata: MapMetadata
    created_at: AwareDatetime

    @field_validator("pgm")
    @classmethod
    def _is_pgm(cls, value: bytes | None) -> bytes | None:
        if value is not None:
            check_pgm(value)
            if len(value) > MAP_INLINE_BYTES:
                raise ValueError(
                    f"inline pgm is limited to {MAP_INLINE_BYTES} bytes; send larger maps in chunks"
                )
        return value

    @model_validator(mode="after")
    def _one_image(self) -> MapUpdate:
        if (self.pgm is None) == (self.image is None):
            raise ValueError("a map carries exactly one of pgm (inline) or image (chunked)")
        return self


class _Chunk(Strict):
    """One piece of a byte string too large for one event, ``index`` of ``count``."""

    index: int = Field(ge=0, le=INT64_MAX)
    count: int = Field(ge=1, le=INT64_MAX)
    data: Base64Bytes = Field(description=f"at most {CHUNK_BYTES} bytes")

    @field_validator("data")
    @classmethod
    def _bounded(cls, value: bytes) -> bytes:
        if len(value) > CHUNK_BYTES:
            raise ValueError(f"a chunk holds at most {CHUNK_BYTES} bytes, not {len(value)}")
        return value

    @model_validator(mode="after")
    def _index_in_range(self) -> _Chunk:
        if self.index >= self.count:
            raise ValueError(f"chunk index {self.index} is not below count {self.count}")
        return self


class MapChunk(_Chunk):
    """One piece of a large map image; the ``map`` event naming its ``map_id`` follows the last."""

    map_id: uuid.UUID


class RosChunk(_Chunk):
    """One piece of a large byte array of a ROS message (an image's pixels, a point cloud's data);
    the ``ros`` event naming ``blob`` (``{"_blob": blob, "length": n}``) follows the last."""

    blob: str = Field(pattern=r"^[0-9a-f]{64}$", description="the SHA-256 of the whole array")

    @classmethod
    def pieces_of(cls, blob: str, data: bytes) -> list[RosChunk]:
        """The chunks that carry ``data`` (``blob``: its SHA-256 in hex, as ``to_blobs`` names
        it), valid by construction (pieces of :func:`split_chunks`, in order): validating them
        would encode every piece in base64 only to decode it again, the dearest step of an image
        on its way to the outbox."""
        pieces = split_chunks(data)
        return [
            cls.model_construct(blob=blob, index=index, count=len(pieces), data=piece)
            for index, piece in enumerate(pieces)
        ]


class RobotStatus(Strict):
    battery_percent: float = Field(ge=0, le=100)
    pose: Pose
    current_waypoint: str | None = Field(default=None, max_length=128)
    processing_rate_hz: float = Field(ge=0)
    outbox_dropped: dict[str, Annotated[int, Field(ge=0)]] | None = Field(
        default=None,
        max_length=16,
        description="events the robot's outbox dropped by its thinning policy since it was made, by type, "
        "and under `unreadable-file` the outbox files it found unreadable at a start and set aside "
        "(the robot client fills it in)",
    )


class LocalisationState(Strict):
    localised: bool
    pose: Pose | None = None


class BeaconSighting(Strict):
    beacon_id: str = Field(min_length=1, max_length=64)
    rssi: int = Field(ge=-127, le=20, description="dBm")
    pose: Pose | None = Field(default=None, description="where the robot was when it heard the beacon")


class Measurement(Strict):
    """One sensor reading taken at a place: a depth sounding, a gas concentration, a temperature.
    The readings a robot takes while recorded under a mission are that mission's sensor data
    (the mission's map shows them, coloured by value)."""

    quantity: str = Field(
        min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$", description="what was measured, e.g. depth"
    )
    value: float = Field(allow_inf_nan=False)
    unit: str = Field(default="", max_length=16, description="e.g. m, ppm, degC")
    pose: Pose = Field(description="where, in the map frame's metres")
    measured_at: AwareDatetime | None = Field(default=None, description="when, if not when sent")


class BehaviourOutcome(Strict):
    name: str = Field(min_length=1, max_length=128)
    object: str | None = Field(default=None, max_length=128, description="what it acted on, e.g. bottle")
    success: bool
    duration_s: float = Field(ge=0)
    error: str | None = Field(default=None, max_length=2048)
    started_at: AwareDatetime | None = None
