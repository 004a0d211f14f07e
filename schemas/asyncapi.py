"""An AsyncAPI 2.6 description of every channel on the bus, generated from the models.

Operators and integrators open it in any AsyncAPI tool to see which exchange carries what,
with which routing key and payload, without reading the code.
"""

from __future__ import annotations

from typing import Any

from pydantic.json_schema import models_json_schema

from fleetbus.schemas.envelope import EVENT_MODELS
from fleetbus.schemas.identity import NAME_PATTERN
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.routing import (
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
    UNASSIGNED_EXCHANGE,
    EventType,
    Topic,
)

REF = "#/components/schemas/{model}"


def _exchange(name: str, kind: str) -> dict[str, Any]:
    return {
        "amqp": {"is": "routingKey", "exchange": {"name": name, "type": kind, "durable": True, "vhost": "/"}}
    }


def _asyncapi_discriminators(schema: Any) -> Any:
    """``schema`` with pydantic's OpenAPI discriminators (``{"propertyName": ..., "mapping": ...}``) as
    AsyncAPI 2.6 writes them: the property's name alone (the ``oneOf`` beside it still lists each model)."""
    if isinstance(schema, list):
        return [_asyncapi_discriminators(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    converted = {key: _asyncapi_discriminators(value) for key, value in schema.items()}
    discriminator = schema.get("discriminator")
    if isinstance(discriminator, dict) and "propertyName" in discriminator:
        converted["discriminator"] = discriminator["propertyName"]
    return converted


def asyncapi_document(version: str = "0.1.0") -> dict[str, Any]:
    models = [*EVENT_MODELS.values(), Notification]
    refs, definitions = models_json_schema([(m, "validation") for m in models], ref_template=REF)
    definitions = _asyncapi_discriminators(definitions)
    messages: dict[str, Any] = {
        f"{event_type.value}_event": {
            "name": f"{event_type.value} event",
            "contentType": "application/json",
            "payload": refs[(model, "validation")],
            "bindings": {"amqp": {"deliveryMode": 2}},
            "headers": {"type": "object", "description": "AMQP properties: user_id = the robot's account"},
        }
        for event_type, model in EVENT_MODELS.items()
    }
    messages["notification"] = {
        "name": "notification",
        "contentType": "application/json",
        "payload": refs[(Notification, "validation")],
    }
    types = [t.value for t in EventType if t is not EventType.BEACON]
    robot = {"schema": {"type": "string", "pattern": NAME_PATTERN.pattern}}
    beacon_headers = {
        "type": "object",
        "required": [BEACON_TYPE_HEADER, BEACON_CODENAME_HEADER],
        "properties": {
            BEACON_TYPE_HEADER: {"const": BEACON_TYPE},
            BEACON_CODENAME_HEADER: {"type": "string", "description": "the sensor's name"},
        },
    }
    return {
        "asyncapi": "2.6.0",
        "info": {
            "title": "fleetbus",
            "version": version,
            "description": "Event backbone of a robot team on RabbitMQ. Every account owns the "
            "exchanges and queues that start with its name; the broker validates user_id.",
        },
        "servers": {
            "rabbitmq": {
                "url": "{host}:5672",
                "protocol": "amqp",
                "protocolVersion": "0.9.1",
                "variables": {"host": {"default": "127.0.0.1"}},
            }
        },
        "channels": {
            "{robot}.{type}": {
                "description": "Events a robot publishes to its own exchange {robot}.events (persistent, "
                "publisher confirms, user_id = robot). The service binds it into fleetbus.ingest.",
                "parameters": {"robot": robot, "type": {"schema": {"type": "string", "enum": types}}},
                "publish": {
                    "operationId": "publishEvent",
                    "message": {"oneOf": [{"$ref": f"#/components/messages/{t}_event"} for t in types]},
                },
                "bindings": _exchange("{robot}.events", "topic"),
            },
            "notify.{topic}": {
                "description": f"Notifications from the service on {NOTIFY_EXCHANGE}, copied by the broker "
                "into each subscribed {user}.inbox queue.",
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
                "bindings": {
                    "amqp": {
                        "is": "queue",
                        "queue": {"name": INGEST_QUEUE, "durable": True, "exclusive": False},
                    }
                },
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
                "bindings": {
                    "amqp": {
                        "is": "queue",
                        "queue": {"name": EXPRESS_QUEUE, "durable": True, "exclusive": False},
                    }
                },
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
                "bindings": {
                    "amqp": {
                        "is": "queue",
                        "queue": {
                            "name": RECORDER_QUEUE,
                            "durable": True,
                            "exclusive": False,
                            "autoDelete": False,
                        },
                    }
                },
            },
            "{robot}.beacon": {
                "description": "Beacons a robot publishes to its own topic exchange {robot}.beacon with the "
                "key {robot}.beacon (the broker refuses any key that does not start with the robot's name). "
                f"Only a message with the headers {BEACON_TYPE_HEADER}: {BEACON_TYPE} and "
                f"{BEACON_CODENAME_HEADER} passes on to {BEACON_EXCHANGE} (to the ingest and every "
                f"operator's stream); the broker sends the rest to {BEACON_DISCARD_EXCHANGE}, and the "
                "workers count them.",
                "parameters": {"robot": robot},
                "publish": {
                    "operationId": "publishBeacon",
                    "message": {
                        "name": "beacon event",
                        "headers": beacon_headers,
                        "payload": refs[(EVENT_MODELS[EventType.BEACON], "validation")],
                    },
                },
                "bindings": _exchange("{robot}.beacon", "topic"),
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
                    "message": {
                        "oneOf": [{"$ref": f"#/components/messages/{t.value}_event"} for t in EventType]
                    },
                },
                "bindings": {
                    "amqp": {
                        "is": "queue",
                        "queue": {"name": "{user}.stream", "durable": True, "exclusive": False},
                    }
                },
            },
            BEACON_DISCARD_QUEUE: {
                "description": f"Beacon messages without the required headers, routed by the alternate "
                f"exchange {BEACON_DISCARD_EXCHANGE}; the workers record and count them by publishing "
                "exchange.",
                "subscribe": {
                    "operationId": "countDiscardedBeacons",
                    "message": {"name": "discarded beacon", "payload": {"type": "string"}},
                },
                "bindings": {
                    "amqp": {"is": "queue", "queue": {"name": BEACON_DISCARD_QUEUE, "durable": True}}
                },
            },
            DEAD_LETTER_QUEUE: {
                "description": "Messages the workers refused, as received: the broker moves each one here "
                f"(basic.nack, the queue's dead-letter exchange {DEAD_LETTER_EXCHANGE}) with its x-death "
                "header; why it was refused is kept in the service's store (`fleetbus dlq`).",
                "subscribe": {
                    "operationId": "readDeadLetters",
                    "message": {"name": "dead letter", "payload": {"type": "string"}},
                },
                "bindings": {"amqp": {"is": "queue", "queue": {"name": DEAD_LETTER_QUEUE, "durable": True}}},
            },
        },
        "components": {"messages": messages, "schemas": definitions.get("$defs", {})},
    }
