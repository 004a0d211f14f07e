"""Reading ROS bags without ROS: ROS 1 ``.bag`` files and ROS 2 bags (a directory with
``metadata.yaml``, or a single ``.db3`` or ``.mcap`` file), with the ``rosbags`` package.

Every problem a bag can have (missing, truncated, corrupt, a type it does not define) is a
:class:`BagError` naming the file and what is wrong.
"""

from __future__ import annotations

import hashlib
import sqlite3
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleetbus.schemas.ros import RosMessage
from fleetbus.workers.recorder.ros_fields import header_stamp, message_fields
from fleetbus.workers.recorder.ros_native import ROS1, ROS2, RosSchema

#: The typestore (``rosbags.typesys.Stores``) that decodes a bag carrying no message definitions
#: (ROS 2 bags recorded before Iron): the standard messages of the latest ROS 2 LTS release.
STANDARD_TYPES = "LATEST"
#: Bytes hashed at a time to recognise a bag imported before.
_BLOCK = 1024 * 1024


class BagError(Exception):
    """A bag that cannot be read; the message names the file and the problem."""


@dataclass(frozen=True)
class BagMessage:
    index: int
    """Position in the bag's log-time order: with the bag's digest, the message's identity."""
    message: RosMessage
    size: int
    """Bytes of the serialised message in the bag."""
    trimmed: bool = False
    """Large arrays were described instead of kept, to stay within the size limit."""
    schema: RosSchema | None = None
    """Its type's definition (the same object for every message of a connection)."""
    blobs: dict[str, bytes] = field(default_factory=dict)
    """Its large byte arrays, by SHA-256 (the fields name them)."""


def bag_digest(path: Path) -> str:
    """SHA-256 of the bag's content (every file of a ROS 2 bag directory, by relative name)."""
    digest = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        name = str(file.relative_to(path)) if path.is_dir() else ""
        digest.update(name.encode() + b"\0")
        with file.open("rb") as stream:
            while block := stream.read(_BLOCK):
                digest.update(block)
    return digest.hexdigest()


def _reader(path: Path) -> Any:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as error:  # the `ros` extra is not installed
        raise BagError(f"{path}: reading bags needs rosbags: pip install 'fleetbus[ros]'") from error
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    # ROS 2 bags before Iron carry no message definitions: decode them with the standard types
    return AnyReader([path], default_typestore=get_typestore(Stores[STANDARD_TYPES]))


#: What rosbags (and the formats under it) raise for a bag it cannot read.
def _read_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError

    errors: list[type[BaseException]] = [AnyReaderError, sqlite3.DatabaseError, struct.error, EOFError]
    try:
        from rosbags.rosbag1 import ReaderError as Reader1Error
        from rosbags.rosbag2 import ReaderError as Reader2Error

        errors += [Reader1Error, Reader2Error]
    except ImportError:  # pragma: no cover (older rosbags)
        pass
    try:
        from mcap.exceptions import McapError

        errors.append(McapError)
    except ImportError:  # pragma: no cover
        pass
    return (*errors, KeyError, ValueError, IndexError, OSError)


def message_count(path: Path) -> int:
    """How many messages the bag says it holds (its index or metadata)."""
    reader = _reader(path)
    try:
        with reader:
            return int(reader.message_count)
    except _read_errors() as error:
        raise BagError(_explain(path, error)) from error


def read_bag(path: Path, max_bytes: int, blob_max: int = 0) -> Iterator[BagMessage]:
    """Every message of the bag in log-time order, deserialised, as a :class:`RosMessage`.

    Raises :class:`BagError` at the first message (or index) that cannot be read, and when
    the bag holds fewer messages than its index says (a truncated file).
    """
    reader = _reader(path)
    index = 0
    schemas: dict[int, RosSchema] = {}
    try:
        with reader:
            expected = int(reader.message_count)
            for connection, log_time, raw in reader.messages():
                decoded = reader.deserialize(raw, connection.msgtype)
                fields, trimmed, blobs = message_fields(decoded, max_bytes, blob_max)
                schema = schemas.get(connection.id)
                if schema is None:
                    schema = schemas[connection.id] = schema_of(reader, connection)
                message = RosMessage(
                    topic=connection.topic,
                    ros_type=connection.msgtype,
                    log_time_ns=log_time,
                    stamp=header_stamp(fields),
                    fields=fields,
                    schema_key=schema.key,
                )
                yield BagMessage(index, message, len(raw), trimmed, schema, blobs)
                index += 1
    except BagError:
        raise
    except _read_errors() as error:
        raise BagError(_explain(path, error, index)) from error
    if index != expected:
        raise BagError(
            f"{path}: holds {index} readable messages where its index says {expected}: "
            "the file is truncated or damaged"
        )


def schema_of(reader: Any, connection: Any) -> RosSchema:
    """The definition of a connection's type: a ROS 1 bag's own text (what its publisher sent), or
    for a ROS 2 bag the one ``rosbags`` writes from the type it decoded the messages with."""
    if reader.is2:
        text, _ = reader.typestore.generate_msgdef(connection.msgtype, ros_version=2)
        return RosSchema(connection.msgtype, ROS2, text)
    text = connection.msgdef.data if connection.msgdef and connection.msgdef.data else None
    if not text:
        text, _ = reader.typestore.generate_msgdef(connection.msgtype, ros_version=1)
    return RosSchema(connection.msgtype, ROS1, text, connection.digest or None)


def _explain(path: Path, error: BaseException, index: int | None = None) -> str:
    where = f" at message {index + 1}" if index else ""
    what = str(error) or type(error).__name__
    if isinstance(error, (struct.error, EOFError)):
        what = f"the file ends early ({what}): truncated"
    return f"{path}: not a readable ROS bag{where}: {what}"
