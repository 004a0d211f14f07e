"""What the recorder makes of one delivered message: its type, its provenance, its body as received.

Where a message was published says what it is:

========================  =================  ===================================
exchange                  type               robot
========================  =================  ===================================
``<robot>.events``        ``<type>`` of the  the exchange's owner (only it may
                          key ``<robot>.     write to it)
                          <type>[.…]``
``<robot>.beacon``        ``beacon`` (the    the exchange's owner
                          broker's discards
                          say why)
``<robot>.requests``      ``request``        the exchange's owner
``fleetbus.notify``       ``notification``   none (the service speaks)
``fleetbus.dlx``          ``dead_letter``    the sender's user id
``<robot>.events``, key   ``ros``, kept as   the exchange's owner
``<robot>.ros``           every ROS message
                          (``schemas.ros``)
anything else             ``other``          the publisher
========================  =================  ===================================

A type name no table could carry, a robot using a name the recorder keeps for itself, or a
type beyond the limit of types, is recorded as ``other`` with the reason. Nothing is dropped.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from decimal import Decimal
from typing import TYPE_CHECKING, Any

from fleetbus.schemas.ros import ROS_SCHEMA_TYPE, ROS_TF_TYPE, ROS_TYPE
from fleetbus.schemas.routing import (
    BEACON_CODENAME_HEADER,
    BEACON_TYPE,
    BEACON_TYPE_HEADER,
    DEAD_LETTER_EXCHANGE,
    NOTIFY_EXCHANGE,
    EventType,
)
from fleetbus.workers.beacon_discards import discard_reason
from fleetbus.workers.recorder.ros_live import as_ros_record
from fleetbus.workers.store.recordings import TYPE_NAME, RecordedMessage

if TYPE_CHECKING:
    from fleetbus.workers.recorder.source import Delivery

NOTIFICATION = "notification"
REQUEST = "request"
DEAD_LETTER = "dead_letter"
REJECTION = "rejection"
"""Where a recorded dead letter keeps why a worker refused it (the store's record of it): the
broker moved the message itself, unchanged, so its headers cannot say."""
OTHER = "other"
#: Types the recorder keeps for itself; ``ros`` holds every ROS message (``fleetbus.schemas.ros``),
#: ``ros_tf`` each transform of a TF message, ``ros_schema`` the definitions of ROS types.
SERVICE_TYPES = (NOTIFICATION, REQUEST, DEAD_LETTER, OTHER, ROS_TYPE, ROS_TF_TYPE, ROS_SCHEMA_TYPE)
#: Types whose records copy what other records hold: left out of an export, a replay or a
#: timeline unless named.
#: (``ros_chunk``: the pieces of a ROS message's large byte array, kept whole in the blob store.)
COPIES = (DEAD_LETTER, ROS_TF_TYPE, ROS_SCHEMA_TYPE, EventType.ROS_CHUNK.value)
#: What ``fleetbus query`` shows besides recorded types: the workers' sequence ledger.
LEDGER_VIEWS = ("gaps", "duplicates")
#: Types whose messages follow a fleetbus schema; everything else is stored as received, flagged unknown.
KNOWN_TYPES = frozenset({t.value for t in EventType} | set(SERVICE_TYPES) - {OTHER})
DEFAULT_MAX_TYPES = 200


class TypeNames:
    """Admits new type names as tables, up to a limit, so no robot can make the store grow tables
    without end."""

    def __init__(self, existing: Iterable[str] = (), limit: int = DEFAULT_MAX_TYPES) -> None:
        self._names = set(existing) | set(SERVICE_TYPES)
        self._limit = limit

    def admit(self, name: str) -> tuple[str, str | None]:
        """The type to record a robot's ``name`` under, and why it is not ``name`` itself."""
        if name in SERVICE_TYPES or name in LEDGER_VIEWS:
            return OTHER, f"type {name!r} is reserved by the recorder"
        if name in self._names:
            return name, None
        if not TYPE_NAME.fullmatch(name):
            return OTHER, f"type {name!r} is not usable as a table name (1-40 of a-z, 0-9, '_')"
        if len(self._names) - len(SERVICE_TYPES) >= self._limit:
            return OTHER, f"type {name!r} is beyond the limit of {self._limit} types"
        self._names.add(name)
        return name, None


@dataclass(frozen=True)
class Origin:
    type: str
    robot_id: str | None
    problem: str | None = None


def origin(
    exchange: str, routing_key: str, user_id: str | None, headers: Mapping[str, Any], names: TypeNames
) -> Origin:
    if exchange == NOTIFY_EXCHANGE:
        return Origin(NOTIFICATION, None)
    if exchange == DEAD_LETTER_EXCHANGE:
        return Origin(DEAD_LETTER, user_id)  # the user id the broker validated when it was sent
    # the owner of <owner>.<kind> is proven: only it may write to that exchange
    owner, _, kind = exchange.partition(".")
    if kind == "requests":
        return Origin(REQUEST, owner)
    if kind == "events":
        if routing_key == f"{owner}.{EventType.ROS.value}":  # the ROS bridge's: see ros_live
            return Origin(EventType.ROS.value, owner)
        type_name, problem = names.admit(routing_key.split(".")[1] if "." in routing_key else "")
        return Origin(type_name, owner, problem)
    if kind == BEACON_TYPE:
        strings = json_safe(dict(headers))
        passed = strings.get(BEACON_TYPE_HEADER) == BEACON_TYPE and BEACON_CODENAME_HEADER in strings
        return Origin(
            EventType.BEACON.value,
            owner,
            None if passed else f"discarded by the broker: {discard_reason(strings)}",
        )
    return Origin(OTHER, user_id)


def json_safe(value: Any) -> Any:
    """AMQP header values as JSON: bytes as text, times in ISO 8601, decimals as numbers."""
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, Decimal):
        return float(value)
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)


def _text(value: Any) -> str | None:
    if value is None:
        return None
    return value.decode("utf-8", errors="replace") if isinstance(value, bytes) else str(value)


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def parse_json(body: bytes) -> tuple[Any, str | None]:
    """The body as a JSON value, or ``(None, why not)``."""
    try:
        return json.loads(body, parse_constant=_reject_constant), None
    except (ValueError, RecursionError) as error:  # UnicodeDecodeError is a ValueError
        return None, f"not JSON ({str(error)[:200]}); kept raw"


def record_key(
    exchange: str,
    user_id: str | None,
    message_id: str | None,
    routing_key: str,
    correlation_id: str | None,
    body: bytes,
) -> str:
    """The same message delivered again gets the same key: by its id when it has one, else by content."""
    digest = hashlib.sha256()
    parts: tuple[str | bytes, ...] = (
        ("id", exchange, user_id or "", message_id)
        if message_id
        else ("content", exchange, user_id or "", routing_key, correlation_id or "", body)
    )
    for part in parts:
        data = part if isinstance(part, bytes) else part.encode()
        digest.update(len(data).to_bytes(8, "big") + data)
    return digest.hexdigest()[:32]


def _aware(moment: datetime | None) -> datetime | None:
    """AMQP timestamps are seconds in UTC; the client may hand them over without a zone."""
    if moment is None:
        return None
    return moment if moment.tzinfo else moment.replace(tzinfo=timezone.utc)


def _envelope_time(document: Any) -> datetime | None:
    value = document.get("sent_at") if isinstance(document, dict) else None
    if not isinstance(value, str):
        return None
    try:
        moment = datetime.fromisoformat(value.replace("Z", "+00:00"))
    except ValueError:
        return None
    return moment if moment.tzinfo else None


def properties_of(message: Delivery) -> dict[str, Any]:
    """What replay and analysis need of the AMQP properties (``None`` ones left out)."""
    values = {
        "content_type": message.content_type,
        "content_encoding": message.content_encoding,
        "headers": json_safe(dict(message.headers or {})) or None,
        "delivery_mode": int(message.delivery_mode) if message.delivery_mode else None,
        "priority": message.priority,
        "correlation_id": message.correlation_id,
        "reply_to": message.reply_to,
        "expiration": json_safe(message.expiration),
        "message_id": message.message_id,
        "timestamp": _aware(message.timestamp).isoformat() if message.timestamp else None,
        "type": message.type,
        "app_id": message.app_id,
    }
    return {name: value for name, value in values.items() if value is not None}


def capture(
    message: Delivery, names: TypeNames, max_bytes: int, now: datetime | None = None
) -> RecordedMessage:
    """The record of a delivered message; never raises for what the message contains."""
    recorded_at = now or datetime.now(timezone.utc)
    exchange, routing_key = message.exchange or "", message.routing_key or ""
    user_id = message.user_id or None
    headers = message.headers or {}
    where = origin(exchange, routing_key, user_id, headers, names)
    body = message.body
    problems = [where.problem] if where.problem else []
    document: Any = None
    raw: bytes | None = None
    if len(body) > max_bytes:
        problems.append(f"body of {len(body)} bytes is over the limit of {max_bytes}; not kept")
        raw = b""
    else:
        document, why_not = parse_json(body)
        if why_not:
            problems.append(why_not)
            raw = body
    envelope = document if isinstance(document, dict) else {}
    message_id = message.message_id or _text(envelope.get("message_id"))
    seq = envelope.get("seq")
    mission = envelope.get("mission_id")
    record = RecordedMessage(
        key=record_key(exchange, user_id, message_id, routing_key, message.correlation_id, body),
        type=where.type,
        recorded_at=recorded_at,
        exchange=exchange,
        routing_key=routing_key,
        user_id=user_id,
        robot_id=where.robot_id,
        message_id=message_id,
        mission_id=mission if isinstance(mission, str) else None,
        sent_at=_envelope_time(envelope) or _aware(message.timestamp),
        seq=seq if isinstance(seq, int) and not isinstance(seq, bool) else None,
        known=where.type in KNOWN_TYPES,
        problem="; ".join(problems) or None,
        document=document,
        raw=raw,
        properties=properties_of(message),
        size=len(body),
        received=body,
    )
    if where.type == EventType.ROS.value and raw is None:
        return as_ros_record(record)  # kept as every ROS message is (fleetbus.schemas.ros)
    return record


def refusal(record: RecordedMessage) -> tuple[str, str] | None:
    """Why a recorded dead letter was refused: ``(reason, detail)``; None when nothing says."""
    if record.type != DEAD_LETTER:
        return None
    kept = record.properties.get(REJECTION)
    if isinstance(kept, dict):
        return str(kept.get("reason", "")), str(kept.get("detail", ""))
    return None
