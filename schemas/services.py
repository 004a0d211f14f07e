"""The services a robot calls over AMQP, as the AsyncAPI document publishes them: each method, its
parameters and its result (JSON Schema).

A call is a message to the caller's own exchange ``<robot>.requests`` with the routing key
``<robot>.<method>``, ``reply_to = amq.rabbitmq.reply-to``, a ``correlation_id`` and an
``expiration``; the reply comes by direct reply-to (:mod:`fleetbus.workers.rpc`). The handlers are
in :mod:`fleetbus.workers.services`, :mod:`fleetbus.workers.beacons` and :mod:`fleetbus.workers.maps`;
a test holds this list to theirs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

#: Where replies come from: RabbitMQ's direct reply-to pseudo-queue.
REPLY_TO = "amq.rabbitmq.reply-to"

MISSION = {
    "type": "string",
    "description": "the mission (default: the one the caller is being recorded under, else `default`)",
}
HAZARD_ID = {"type": "integer", "minimum": 1, "description": "the hazard's number within its mission"}
MINUTES = {
    "type": "number",
    "exclusiveMinimum": 0,
    "description": "how far back to look (default 10; at most FLEETBUS_BEACON_WINDOW_MAX_MINUTES, 60 "
    "by default)",
}
BEACON_ID = {"type": "string", "minLength": 1}
TIME = {"type": ["string", "null"], "format": "date-time"}

HAZARD: dict[str, Any] = {
    "type": "object",
    "description": "A hazard of the registry: held until the gate opens, then announced, claimed by "
    "one warden, reached, cleared.",
    "required": ["mission_id", "hazard_id", "robot_id", "epoch", "seq", "event", "state", "received_at"],
    "properties": {
        "mission_id": {"type": "string"},
        "hazard_id": HAZARD_ID,
        "robot_id": {"type": "string", "description": "the robot that detected it"},
        "epoch": {"type": "string"},
        "seq": {"type": "integer", "minimum": 0},
        "event": {"$ref": "#/components/schemas/HazardEvent"},
        "state": {"type": "string", "enum": ["held", "announced", "claimed", "reached", "cleared"]},
        "received_at": {"type": "string", "format": "date-time"},
        "announced_at": TIME,
        "claimed_by": {"type": ["string", "null"]},
        "claimed_at": TIME,
        "reached_at": TIME,
        "cleared_at": TIME,
        "held_reason": {"type": ["string", "null"]},
        "version": {"type": "integer"},
        "site": {"type": ["string", "null"]},
        "site_hazard_id": {"type": ["integer", "null"]},
    },
}
ANY_OBJECT: dict[str, Any] = {"type": "object"}


@dataclass(frozen=True)
class Method:
    name: str
    summary: str
    params: dict[str, Any] = field(default_factory=dict)
    """The parameters' properties (JSON Schema); the request body is a JSON object of them."""
    required: tuple[str, ...] = ()
    result: dict[str, Any] = field(default_factory=dict)

    def params_schema(self) -> dict[str, Any]:
        return {"type": "object", "properties": self.params, "required": list(self.required)}


def _hazard_step(name: str, what: str) -> Method:
    return Method(
        name,
        what,
        {"hazard_id": HAZARD_ID, "mission_id": MISSION},
        ("hazard_id",),
        HAZARD,
    )


METHODS: tuple[Method, ...] = (
    Method(
        "hazard.get",
        "one hazard of the mission, if the caller reported it or it is open to the caller as "
        "`hazard.open` has it; another warden's, a cleared one or a site's is refused (`ok: false`)",
        {"hazard_id": HAZARD_ID, "mission_id": MISSION},
        ("hazard_id",),
        HAZARD,
    ),
    Method(
        "hazard.open",
        "the mission's hazards not yet cleared that are open to the caller, in id order: those no "
        "warden holds (held ones included, their `state` says) and those the caller claimed; what a "
        "warden rebuilds its list from. A hazard another warden claimed or reached is left out, as "
        "is a site's (its own wardens')",
        {"mission_id": MISSION},
        (),
        {"type": "array", "items": HAZARD},
    ),
    _hazard_step("hazard.claim", "claim a hazard for the calling warden (refused if another holds it)"),
    _hazard_step("hazard.release", "give a claimed hazard back"),
    _hazard_step("hazard.reached", "the claiming warden reached the hazard"),
    _hazard_step("hazard.cleared", "the claiming warden cleared the hazard (once it reported it reached)"),
    Method(
        "wardens",
        "the wardens of the team: localised, when last reported, in service",
        result={"type": "array", "items": ANY_OBJECT},
    ),
    Method("beacon.info", "one beacon of the registry", {"beacon_id": BEACON_ID}, ("beacon_id",), ANY_OBJECT),
    Method(
        "beacon.stranded",
        "the beacons heard recently (people who may be stranded), with where",
        {"minutes": MINUTES},
        (),
        {"type": "array", "items": ANY_OBJECT},
    ),
    Method(
        "beacon.goal",
        "the next stranded beacon to visit, or null",
        {"minutes": MINUTES},
        (),
        {"type": ["object", "null"]},
    ),
    Method("beacon.visited", "mark a beacon visited", {"beacon_id": BEACON_ID}, ("beacon_id",), ANY_OBJECT),
    Method(
        "map.latest",
        "a stored map version (the newest by default): its metadata and how many chunks",
        {"version": {"type": "integer"}},
        (),
        ANY_OBJECT,
    ),
    Method(
        "map.chunk",
        "one chunk of a stored map version's PGM image, base64",
        {"version": {"type": "integer", "minimum": 0}, "index": {"type": "integer", "minimum": 0}},
        ("version", "index"),
        {
            "type": "object",
            "required": ["version", "index", "data"],
            "properties": {
                "version": {"type": "integer"},
                "index": {"type": "integer"},
                "data": {"type": "string", "contentEncoding": "base64"},
            },
        },
    ),
)


def reply_schema(result: dict[str, Any]) -> dict[str, Any]:
    """A reply: the result, or a refusal (the caller's to fix), or the service's own failure."""
    return {
        "oneOf": [
            {
                "type": "object",
                "required": ["ok", "result"],
                "properties": {"ok": {"const": True}, "result": result},
            },
            {
                "type": "object",
                "required": ["ok", "error"],
                "properties": {
                    "ok": {"const": False},
                    "error": {"type": "string", "description": "why, in words"},
                    "internal": {
                        "type": "boolean",
                        "description": "true: the service failed on it (its bug, logged under the "
                        "reference the error gives), not the request's fault",
                    },
                },
            },
        ]
    }
