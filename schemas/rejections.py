"""Why the workers refuse an event: each reason code, and what it means to the robot that sent it.

The workers dead-letter a refused message with one of these codes and a detail naming what is
wrong (``fleetbus dlq``); the AsyncAPI document lists them as the outcomes a publisher can meet.
"""

from __future__ import annotations

from enum import Enum


class RejectReason(str, Enum):
    TOO_LARGE = "too-large"
    NO_USER_ID = "no-user-id"
    CONTENT_TYPE = "content-type"
    NOT_PERSISTENT = "not-persistent"
    UNKNOWN_TYPE = "unknown-type"
    NOT_JSON = "not-json"
    SCHEMA = "schema"
    IDENTITY_MISMATCH = "identity-mismatch"
    WRONG_EXCHANGE = "wrong-exchange"
    UNKNOWN_ROBOT = "unknown-robot"
    BAD_MAP = "bad-map"
    SEQUENCE_REUSED = "sequence-reused"
    DELIVERY_LIMIT = "delivery-limit"
    INTERNAL_ERROR = "internal-error"
    """Not the message's fault: handling it raised an unexpected error (a bug, logged with its traceback)."""


#: What each reason means, in the order the workers check (the first that applies is given).
MEANINGS: dict[RejectReason, str] = {
    RejectReason.TOO_LARGE: "the body is larger than the limit (FLEETBUS_MAX_MESSAGE_BYTES)",
    RejectReason.NO_USER_ID: "no user_id property: the origin is unproven",
    RejectReason.CONTENT_TYPE: "the content_type property is missing or not application/json (UTF-8)",
    RejectReason.NOT_PERSISTENT: "delivery_mode is not 2 (persistent)",
    RejectReason.UNKNOWN_TYPE: "the routing key is not <robot>.<type> with a known type",
    RejectReason.NOT_JSON: "the body is not JSON",
    RejectReason.SCHEMA: "the body fails the event's schema: a required field missing, a field unknown "
    "or out of range (the detail names each)",
    RejectReason.IDENTITY_MISMATCH: "user_id, the routing key's robot and the body's robot_id and type "
    "do not agree",
    RejectReason.WRONG_EXCHANGE: "published to another exchange than the type's (<robot>.events, or "
    "<robot>.beacon for beacons)",
    RejectReason.UNKNOWN_ROBOT: "a beacon sighting from a robot the team does not know",
    RejectReason.BAD_MAP: "a map that is incomplete or corrupt (its chunks, size or sha256)",
    RejectReason.SEQUENCE_REUSED: "the same (robot_id, epoch, seq) as a stored event, with another type "
    "or body (a resend of the same event is a duplicate, counted, not refused)",
    RejectReason.DELIVERY_LIMIT: "the worker began to handle it too often and never finished",
    RejectReason.INTERNAL_ERROR: "the worker failed on it (a bug of the service, not the message's fault)",
}
