"""The channels of the AsyncAPI document (:mod:`fleetbus.schemas.asyncapi`): a robot's events, its
beacons and inbox, its service calls and their replies, and what the service and the operators use."""

from __future__ import annotations

from typing import Any

from fleetbus.schemas.envelope import EVENT_MODELS
from fleetbus.schemas.properties import PERSISTENT
from fleetbus.schemas.rejections import MEANINGS
from fleetbus.schemas.routing import (
    ANNOUNCED_TO_HEADER,
    BEACON_CODENAME_HEADER,
    BEACON_DISCARD_EXCHANGE,
    BEACON_DISCARD_QUEUE,
    BEACON_EXCHANGE,
    BEACON_TYPE,
    BEACON_TYPE_HEADER,
    DEAD_LETTER_EXCHANGE,
    DEAD_LETTER_QUEUE,
    EXPRESS_QUEUE,
    EXPRESS_TYPES,
    INGEST_EXCHANGE,
    INGEST_QUEUE,
    NOTIFY_EXCHANGE,
    RECORDED_EXCHANGES,
    RECORDER_QUEUE,
    SHARD_EXCHANGE,
    SUBSCRIPTIONS,
    UNASSIGNED_EXCHANGE,
    EventType,
    Topic,
    event_routing_key,
    events_exchange,
    inbox_queue,
    request_routing_key,
    requests_exchange,
)
from fleetbus.schemas.services import METHODS, REPLY_TO

#: The version of the AMQP bindings the document's ``bindings`` follow (AsyncAPI's bindings repository).
AMQP_BINDING = "0.3.0"
EVENT_TRAIT = "#/components/messageTraits/event"
REQUEST_TRAIT = "#/components/messageTraits/request"


def _exchange(name: str, kind: str) -> dict[str, Any]:
    return {
        "amqp": {
            "is": "routingKey",
            "exchange": {"name": name, "type": kind, "durable": True, "autoDelete": False, "vhost": "/"},
            "bindingVersion": AMQP_BINDING,
        }
    }


def _queue(name: str, **options: bool) -> dict[str, Any]:
    queue = {"name": name, "durable": True, "exclusive": False, "autoDelete": False, "vhost": "/", **options}
    return {"amqp": {"is": "queue", "queue": queue, "bindingVersion": AMQP_BINDING}}


def _publishing(**options: Any) -> dict[str, Any]:
    """A robot's publish operation's AMQP binding: its own user_id, and ``options``."""
    return {"amqp": {"userId": "{robot}", **options, "bindingVersion": AMQP_BINDING}}


def gate_rule() -> str:
    return (
        "**The hazard gate.** Hazards are held until at least one warden is in service and every "
        "warden in service is localised; then they are announced in the order detected. A warden "
        "counts as localised once its newest `localisation` event (by `sent_at`; an event without "
        "one is stamped when the worker reads it) says `localised: true`. So a warden gets hazard "
        "notifications only once localised: it publishes its localisation first, then reads its inbox."
    )


#: What each event type's channel says beyond its schema.
EVENT_NOTES: dict[EventType, str] = {
    EventType.HAZARD: "The service registers it in the robot's mission and announces it to the wardens "
    "in service by their inboxes once the gate is open (below); until then it is held, in order.",
    EventType.LOCALISATION: "A warden's `localised` state opens or holds the hazard gate (below).",
    EventType.STATUS: "Telemetry; a `battery_percent` that falls under the threshold notifies the "
    "operators once (topic `battery`), again only after it was above it.",
    EventType.MAP: "A new map: exactly one of inline `pgm` (a PGM of at most 256 KiB, whose header "
    "matches its pixels) or `image` naming the `map_chunk` events sent before it; `free_thresh` below "
    "`occupied_thresh`. Once complete it is stored and announced on the topic `map`.",
    EventType.MAP_CHUNK: "One piece of a large map image, before the `map` event that names it; "
    "`index` below `count`.",
    EventType.BEHAVIOUR: "The outcome of a behaviour (what was tried on what, success, duration).",
    EventType.ROS: "A ROS message, recorded (the ROS bridge publishes them). A byte array over 64 KiB "
    '(an image\'s pixels) is named as `{"_blob": sha256, "length": n}` and travels before it as '
    "`ros_chunk` events; one over the robot's bound (`FLEETBUS_ROS_BLOB_MAX_BYTES`) is only described "
    '(`{"_truncated": true, "length": n, "sha256": ...}`).',
    EventType.ROS_CHUNK: "One piece (at most 512 KiB) of a large byte array of a ROS message, before the "
    "`ros` event that names its `blob`; `index` (below `count`) of `count`, in order. Sent again, it is "
    "kept once.",
    EventType.MEASUREMENT: "A sensor reading (`quantity`, `value`, `unit`) taken at `pose`. Recorded under "
    "the mission the robot is checked in to, it is the mission's sensor data: the mission's page maps it, "
    "coloured by value.",
}


def event_channels(robot: dict[str, Any]) -> dict[str, Any]:
    """One channel per event type a robot publishes to its events exchange: the routing key."""
    channels: dict[str, Any] = {}
    for event_type in EventType:
        if event_type is EventType.BEACON:
            continue
        exchange = events_exchange("{robot}")
        note = EVENT_NOTES[event_type]
        if event_type in EXPRESS_TYPES:
            note += " " + gate_rule()
        channels[event_routing_key("{robot}", event_type)] = {
            "description": f"`{event_type.value}` events a robot publishes to its own topic exchange "
            f"`{exchange}` with the routing key `{{robot}}.{event_type.value}`. {note}",
            "parameters": {"robot": robot},
            "publish": {
                "operationId": f"publish_{event_type.value}",
                "summary": f"publish a {event_type.value} event",
                "bindings": _publishing(deliveryMode=PERSISTENT, mandatory=True),
                "message": {"$ref": f"#/components/messages/{event_type.value}_event"},
            },
            "bindings": _exchange(exchange, "topic"),
        }
    return channels


def robot_channels(robot: dict[str, Any], beacon_headers: dict[str, Any], refs: Any) -> dict[str, Any]:
    """The robot's beacons and its inbox."""
    kinds = ", ".join(
        f"{kind.value}s: {', '.join(t.value for t in topics) or 'none'}"
        for kind, topics in SUBSCRIPTIONS.items()
    )
    return {
        "{robot}.beacon": {
            "description": "Beacons a robot publishes to its own topic exchange {robot}.beacon with the "
            "key {robot}.beacon (the broker refuses any key that does not start with the robot's name). "
            f"Only a message with the headers {BEACON_TYPE_HEADER}: {BEACON_TYPE} and "
            f"{BEACON_CODENAME_HEADER} passes on to {BEACON_EXCHANGE} (to the ingest and every "
            f"operator's stream); the broker sends the rest to {BEACON_DISCARD_EXCHANGE}, and the "
            "workers count them.",
            "parameters": {"robot": robot},
            "publish": {
                "operationId": "publish_beacon",
                "bindings": _publishing(deliveryMode=PERSISTENT, mandatory=True),
                "message": {
                    "name": "beacon event",
                    "headers": beacon_headers,
                    "payload": refs[(EVENT_MODELS[EventType.BEACON], "validation")],
                    "bindings": {"amqp": {"messageType": BEACON_TYPE, "bindingVersion": AMQP_BINDING}},
                    "traits": [{"$ref": EVENT_TRAIT}],
                },
            },
            "bindings": _exchange("{robot}.beacon", "topic"),
        },
        inbox_queue("{robot}"): {
            "description": "The account's own durable queue of notifications (made with the account): "
            "consume it with acknowledgements. What arrives depends on the robot's kind ("
            + kinds
            + "; operators: every topic). Maps come through the binding `notify.map`; hazards are put "
            "in each warden's inbox by name, and only to wardens in service once the gate is open. "
            + gate_rule()
            + " A notification may come twice (sent again when the service could not be sure the "
            "broker took it): skip one that says what you last knew of its subject, by its topic and "
            "event `message_id`, in the same `hazard_state` with the same `claimed_by` (a step you took "
            "yourself counts). A hazard in another state is news, an earlier one too: an operator who "
            "releases a warden's claim makes it `announced` again. `late: true` marks a hazard announced "
            "long after the robot sent the event (other topics never set it). The inbox is bounded "
            "(`FLEETBUS_INBOX_MAX`, 10,000 messages or 100 MB by default): when it is full its oldest "
            "notifications are dropped, so a warden back after a long absence rebuilds its list with "
            "`hazard.open` (and `map.latest`).",
            "parameters": {"robot": robot},
            "subscribe": {
                "operationId": "receive_notifications",
                "bindings": {"amqp": {"ack": True, "bindingVersion": AMQP_BINDING}},
                "message": {"$ref": "#/components/messages/notification"},
            },
            "bindings": _queue(inbox_queue("{robot}")),
        },
    }


def service_channels(robot: dict[str, Any]) -> dict[str, Any]:
    """One channel per service method (the routing key on the caller's requests exchange), and the
    reply-to channel the answers come on."""
    channels: dict[str, Any] = {}
    for method in METHODS:
        channels[request_routing_key("{robot}", method.name)] = {
            "description": f"Call `{method.name}`: {method.summary}. Published to the caller's own "
            f"topic exchange `{requests_exchange('{robot}')}`; the answer comes on `{REPLY_TO}` "
            f"(`x-reply`).",
            "parameters": {"robot": robot},
            "publish": {
                "operationId": f"call_{method.name}",
                "summary": method.summary,
                "bindings": _publishing(mandatory=True),
                "message": {"$ref": f"#/components/messages/request.{method.name}"},
                "x-reply": {"$ref": f"#/components/messages/reply.{method.name}"},
            },
            "bindings": _exchange(requests_exchange("{robot}"), "topic"),
        }
    channels[REPLY_TO] = {
        "description": "RabbitMQ's direct reply-to: the answers to the calls this connection made, each "
        'with its call\'s `correlation_id`: `{"ok": true, "result": ...}`, `{"ok": false, "error": "..."}` '
        'for a call the service refuses (the caller\'s to fix), or `{"ok": false, "internal": true, '
        '"error": "..."}` when the service failed on it. A call with no reply within its expiration '
        "was not answered (the workers are down or busy).",
        "subscribe": {
            "operationId": "receive_replies",
            "bindings": {"amqp": {"ack": False, "bindingVersion": AMQP_BINDING}},
            "message": {"oneOf": [{"$ref": f"#/components/messages/reply.{m.name}"} for m in METHODS]},
        },
        "bindings": _queue(REPLY_TO, durable=False, exclusive=True, autoDelete=True),
    }
    return channels


def _dead_letter_reasons() -> str:
    return "; ".join(f"`{reason.value}`: {meaning}" for reason, meaning in MEANINGS.items())


def service_side_channels(robot: dict[str, Any]) -> dict[str, Any]:
    """What the service and the operators use: notifications, the ingest lanes, the recorder,
    commands, streams, discarded beacons and dead letters."""
    return {
        "notify.{topic}": {
            "description": f"Notifications from the service on {NOTIFY_EXCHANGE}, copied by the broker "
            "into each subscribed {user}.inbox queue (operators: every topic; hazards reach wardens by "
            f"name instead, and their copy here names them in the header {ANNOUNCED_TO_HEADER}).",
            "parameters": {"topic": {"schema": {"type": "string", "enum": [t.value for t in Topic]}}},
            "subscribe": {
                "operationId": "receiveNotification",
                "message": {"$ref": "#/components/messages/notification"},
            },
            "bindings": _exchange(NOTIFY_EXCHANGE, "topic"),
        },
        INGEST_QUEUE: {
            "description": f"The ingest shards the workers consume: {INGEST_QUEUE} (shard 0), "
            f"{INGEST_QUEUE}.1, .2 ... (FLEETBUS_INGEST_SHARDS). {INGEST_EXCHANGE} feeds the topic "
            f"exchange {SHARD_EXCHANGE}, where each robot is bound to one shard with the keys "
            "{robot}.{type}, one for each of these types, when its account is made, so all of one "
            "robot's events of these types keep their order in one quorum queue with a single active "
            f"consumer. A message no binding matches goes to shard 0 through the alternate exchange "
            f"{UNASSIGNED_EXCHANGE}. "
            "Only the service's workers read them; several workers share the shards.",
            "subscribe": {
                "operationId": "ingestEvents",
                "message": {
                    "oneOf": [
                        {"$ref": f"#/components/messages/{t.value}_event"}
                        for t in EventType
                        if t not in EXPRESS_TYPES
                    ]
                },
            },
            "bindings": _queue(INGEST_QUEUE),
        },
        EXPRESS_QUEUE: {
            "description": "The express lane: every robot's "
            + " and ".join(t.value for t in EXPRESS_TYPES)
            + f" events, bound from {SHARD_EXCHANGE} with *.<type>, so that none waits behind a "
            "robot's telemetry, maps or resync. A classic queue with a single active consumer, read "
            "by the worker that holds shard 0; one robot's events in it keep their order.",
            "subscribe": {
                "operationId": "ingestExpressEvents",
                "message": {
                    "oneOf": [{"$ref": f"#/components/messages/{t.value}_event"} for t in EXPRESS_TYPES]
                },
            },
            "bindings": _queue(EXPRESS_QUEUE),
        },
        RECORDER_QUEUE: {
            "description": "A copy of every message published to "
            + ", ".join(RECORDED_EXCHANGES)
            + " (robots' events of any type, notifications, service requests, dead letters), kept by "
            "the recorder one collection per type, as received, with user_id, exchange and routing key. "
            "Types other than the event types above are recorded too, flagged unknown. Only the "
            "account fleetbus-recorder may read it.",
            "subscribe": {
                "operationId": "recordEverything",
                "message": {
                    "name": "any message",
                    "payload": {"description": "the body as published: JSON when it parses, else bytes"},
                },
            },
            "bindings": _queue(RECORDER_QUEUE),
        },
        "{robot}.{command}": {
            "description": "Commands an operator publishes to its exchange {operator}.commands "
            "(user_id = operator). While the operator has the robot mounted, the service binds "
            "the robot's queue {robot}.commands to it with the key {robot}.#; otherwise a command "
            "is unroutable. Commands expire after 30 s in the queue.",
            "parameters": {"robot": robot, "command": {"schema": {"type": "string"}}},
            "subscribe": {
                "operationId": "receiveCommand",
                "message": {"name": "command", "payload": {"type": "object"}},
            },
            "bindings": _exchange("{operator}.commands", "topic"),
        },
        "{user}.stream": {
            "description": f"An operator's stream queue: every message of {BEACON_EXCHANGE}, and the "
            "events of each robot it has mounted (bound by the service on mount). Read with "
            "x-stream-offset (`fleetbus tail`); delivery keeps the original exchange, routing key "
            "and user_id.",
            "parameters": {"user": robot},
            "subscribe": {
                "operationId": "followStream",
                "message": {"oneOf": [{"$ref": f"#/components/messages/{t.value}_event"} for t in EventType]},
            },
            "bindings": _queue("{user}.stream"),
        },
        BEACON_DISCARD_QUEUE: {
            "description": f"Beacon messages without the required headers, routed by the alternate "
            f"exchange {BEACON_DISCARD_EXCHANGE}; the workers record and count them by publishing "
            "exchange.",
            "subscribe": {
                "operationId": "countDiscardedBeacons",
                "message": {"name": "discarded beacon", "payload": {"type": "string"}},
            },
            "bindings": _queue(BEACON_DISCARD_QUEUE),
        },
        DEAD_LETTER_QUEUE: {
            "description": "Messages the workers refused, as received: the broker moves each one here "
            f"(basic.nack, the queue's dead-letter exchange {DEAD_LETTER_EXCHANGE}) with its x-death "
            "header; why it was refused is kept in the service's store (`fleetbus dlq`, the console's "
            "Dead letters page): a reason and a detail naming what is wrong. The reasons, in the order "
            "the workers check: " + _dead_letter_reasons() + ".",
            "subscribe": {
                "operationId": "readDeadLetters",
                "message": {"name": "dead letter", "payload": {"type": "string"}},
            },
            "bindings": _queue(DEAD_LETTER_QUEUE),
            "x-reasons": {reason.value: meaning for reason, meaning in MEANINGS.items()},
        },
    }
