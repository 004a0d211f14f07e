"""An AsyncAPI 2.6 description of every channel on the bus, generated from the models: the
contract for a robot written in any language.

It says where a robot connects (AMQPS, the port `fleetbus users add` hands out), where it
publishes each event type and with which routing key and AMQP properties, which body fields are
required, the size limit, where its notifications arrive and when (the hazard gate), how it
calls the services and where the replies come, and what happens to a message that breaks the
contract. Operators and integrators open it in any AsyncAPI tool; ``tests/peers/robot.mjs`` is a
Node.js robot built from it alone.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlsplit

from pydantic.json_schema import models_json_schema

from fleetbus.defaults import DEFAULT_MAX_MESSAGE_BYTES
from fleetbus.schemas.asyncapi_channels import (
    AMQP_BINDING,
    EVENT_TRAIT,
    REQUEST_TRAIT,
    event_channels,
    gate_rule,
    robot_channels,
    service_channels,
    service_side_channels,
)
from fleetbus.schemas.envelope import EVENT_MODELS
from fleetbus.schemas.identity import NAME_PATTERN
from fleetbus.schemas.notifications import Notification
from fleetbus.schemas.properties import EVENT_CONTENT_TYPE, PERSISTENT
from fleetbus.schemas.routing import BEACON_CODENAME_HEADER, BEACON_TYPE, BEACON_TYPE_HEADER
from fleetbus.schemas.services import METHODS, REPLY_TO, reply_schema

REF = "#/components/schemas/{model}"
DEFAULT_PORT = {"amqps": 5671, "amqp": 5672}
CACERTFILE_NOTE = (
    "Verify the broker's certificate with fleetbus's CA file (`ca.pem`: `fleetbus certs show`, or the "
    "API's `GET /ca.pem`) and the host name. The URL `fleetbus users add` prints may end in "
    "`?cacertfile=PATH`: that is a RabbitMQ/Erlang URI parameter (the Python client and shovels read "
    "it); other clients ignore it, so give the CA file to your TLS library yourself."
)


def _asyncapi_schema(schema: Any) -> Any:
    """pydantic's JSON Schema (draft 2020-12, OpenAPI flavour) as AsyncAPI 2.6's Schema Object (a
    superset of draft 07) writes it, so that any draft-07 validator checks what pydantic checks:
    a discriminator object becomes the property's name alone (the ``oneOf`` beside it still lists
    each model); a tuple's ``prefixItems`` becomes ``items`` as a list with no additional items;
    pydantic's ``format: base64`` becomes the standard ``contentEncoding: base64``."""
    if isinstance(schema, list):
        return [_asyncapi_schema(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    converted = {key: _asyncapi_schema(value) for key, value in schema.items()}
    discriminator = schema.get("discriminator")
    if isinstance(discriminator, dict) and "propertyName" in discriminator:
        converted["discriminator"] = discriminator["propertyName"]
    if "prefixItems" in converted:
        converted["items"] = converted.pop("prefixItems")
        converted["additionalItems"] = False
    if converted.get("format") == "base64":
        del converted["format"]
        converted["contentEncoding"] = "base64"
    return converted


def _server(broker_url: str | None) -> dict[str, Any]:
    """Where robots connect: the scheme, host and port of ``broker_url`` (what `fleetbus users add`
    hands out here) as the variables' defaults, else AMQPS on its standard port."""
    parts = urlsplit(broker_url or "amqps://localhost")
    protocol = parts.scheme if parts.scheme in DEFAULT_PORT else "amqps"
    port = parts.port or DEFAULT_PORT[protocol]
    return {
        "url": "{host}:{port}",
        "protocol": protocol,
        "protocolVersion": "0.9.1",
        "description": "RabbitMQ. Connect with the URL `fleetbus users add NAME` prints (shown once): "
        "its scheme, host, port, virtual host (the path; `/` when none), the account's name and password. "
        + (CACERTFILE_NOTE if protocol == "amqps" else "This broker is reached without TLS.")
        + " An account may touch only exchanges and queues that start with its name and publish only "
        "routing keys that start with it; everything it needs exists once the account is made: declare "
        "nothing.",
        "variables": {
            "host": {"default": parts.hostname or "localhost", "description": "the host of the URL"},
            "port": {
                "default": str(port),
                "description": "the port of the URL `fleetbus users add` prints: 5671 for AMQPS on a "
                "broker you run; the private node's AMQPS port is chosen at its first start "
                "(`fleetbus broker status`)",
            },
        },
        "security": [{"password": []}, {"certificate": []}],
    }


def _event_trait(max_message_bytes: int) -> dict[str, Any]:
    """What every event message carries besides its body, and what happens when it does not."""
    return {
        "contentType": EVENT_CONTENT_TYPE,
        "description": f"Every event: one JSON envelope (UTF-8) of at most {max_message_bytes} bytes "
        "(larger ones are refused as `too-large`), published persistent to the robot's own exchange, "
        "with publisher confirms and `mandatory`. The AMQP properties are in `x-amqp-properties`. "
        "**Resending is safe**: an event is known by (`robot_id`, `epoch`, `seq`); sent again with the "
        "same `type` and `body` (compared as JSON: key order, white space, fields left at their "
        "defaults, `sent_at` and `message_id` do not matter) it is a duplicate, counted "
        "(`fleetbus query duplicates`), never stored twice nor refused. The same key with another "
        "type or body is refused as `sequence-reused`. A body without `message_id` gets one derived "
        "from its key and content, the same at every send. `epoch` is the start of the publishing "
        "program (UTC time to the millisecond, then 8 random hex digits); `seq` counts 0, 1, 2... "
        "within it. A refused message goes to the dead-letter queue with its reason "
        "(`fleetbus dlq`; the reasons: the channel `fleetbus.dead-letters`).",
        "x-amqp-properties": {
            "type": "object",
            "required": ["user_id", "content_type", "delivery_mode"],
            "properties": {
                "user_id": {
                    "type": "string",
                    "pattern": NAME_PATTERN.pattern,
                    "description": "the account's name, the same as the routing key's `{robot}` and the "
                    "body's `robot_id`: the broker checks it against the login and closes the channel "
                    "(406 PRECONDITION_FAILED) on any other; a message without it is refused as "
                    "`no-user-id`",
                },
                "content_type": {
                    "const": EVENT_CONTENT_TYPE,
                    "description": "a `charset=utf-8` parameter may follow; anything else, or none, is "
                    "refused as `content-type`",
                },
                "delivery_mode": {
                    "const": PERSISTENT,
                    "description": "persistent: the broker keeps it on disk until the workers stored it; "
                    "a transient one is refused as `not-persistent`",
                },
                "message_id": {
                    "type": "string",
                    "description": "the body's `message_id` (any id of your own when the body has none): "
                    "logs, dead letters and `fleetbus trace` name the message by it. Not checked",
                },
            },
        },
        "x-max-body-bytes": max_message_bytes,
    }


def _request_trait() -> dict[str, Any]:
    return {
        "contentType": EVENT_CONTENT_TYPE,
        "correlationId": {
            "description": "the AMQP `correlation_id` property: the reply carries it back",
            "location": "$message.header#/correlation_id",
        },
        "description": "A service call: the parameters as a JSON object (`content_type` "
        f"`{EVENT_CONTENT_TYPE}`: a call of another content type, or none, is refused without being "
        "processed), published to the caller's "
        f"own exchange with `user_id` = the caller, `reply_to` = `{REPLY_TO}` (consume it, with "
        "`no_ack`, on the same channel before publishing), a `correlation_id`, and an `expiration` "
        "(milliseconds) no longer than the caller waits. The reply comes on the reply-to channel.",
        "x-amqp-properties": {
            "type": "object",
            "required": ["user_id", "reply_to", "correlation_id", "content_type"],
            "properties": {
                "user_id": {"type": "string", "description": "the caller's account name"},
                "reply_to": {"const": REPLY_TO},
                "correlation_id": {"type": "string"},
                "expiration": {"type": "string", "description": "milliseconds, as text"},
                "content_type": {"const": EVENT_CONTENT_TYPE},
            },
        },
    }


def asyncapi_document(
    version: str = "0.1.0",
    *,
    broker_url: str | None = None,
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> dict[str, Any]:
    """The document; ``broker_url``: the broker robots are handed here (its scheme, host and port
    become the server's), ``max_message_bytes``: the workers' limit."""
    models = [*EVENT_MODELS.values(), Notification]
    refs, definitions = models_json_schema([(m, "validation") for m in models], ref_template=REF)
    definitions = _asyncapi_schema(definitions)
    messages: dict[str, Any] = {
        f"{event_type.value}_event": {
            "name": f"{event_type.value} event",
            "title": f"{event_type.value} event",
            "payload": refs[(model, "validation")],
            "bindings": {"amqp": {"messageType": event_type.value, "bindingVersion": AMQP_BINDING}},
            "traits": [{"$ref": EVENT_TRAIT}],
        }
        for event_type, model in EVENT_MODELS.items()
    }
    messages["notification"] = {
        "name": "notification",
        "contentType": EVENT_CONTENT_TYPE,
        "payload": refs[(Notification, "validation")],
    }
    for method in METHODS:
        messages[f"request.{method.name}"] = {
            "name": f"{method.name} request",
            "summary": method.summary,
            "payload": method.params_schema(),
            "bindings": {"amqp": {"messageType": method.name, "bindingVersion": AMQP_BINDING}},
            "traits": [{"$ref": REQUEST_TRAIT}],
        }
        messages[f"reply.{method.name}"] = {
            "name": f"{method.name} reply",
            "contentType": EVENT_CONTENT_TYPE,
            "payload": reply_schema(method.result),
        }
    robot = {"schema": {"type": "string", "pattern": NAME_PATTERN.pattern}, "description": "an account name"}
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
            "description": "Event backbone of a robot team on RabbitMQ: the contract for a robot in "
            "any language. A robot publishes its events to its own exchange `{robot}.events` (the "
            "channels `{robot}.<type>`; beacons to `{robot}.beacon`), reads the notifications it is "
            "sent from its queue `{robot}.inbox`, and calls the services over its exchange "
            "`{robot}.requests` (the channels `{robot}.<method>`), their replies coming by direct "
            "reply-to. Every account owns the exchanges and queues that start with its name; the "
            "broker validates `user_id`. The workers check every event (properties: "
            "`components.messageTraits.event`; body: the payload schemas, whose `required` lists are "
            "the fields a message must carry) and store it once; what they refuse is dead-lettered "
            "with a reason. " + gate_rule(),
        },
        "servers": {"fleetbus": _server(broker_url)},
        "channels": {
            **event_channels(robot),
            **robot_channels(robot, beacon_headers, refs),
            **service_channels(robot),
            **service_side_channels(robot),
        },
        "components": {
            "messages": messages,
            "schemas": definitions.get("$defs", {}),
            "messageTraits": {"event": _event_trait(max_message_bytes), "request": _request_trait()},
            "securitySchemes": {
                "password": {
                    "type": "userPassword",
                    "description": "the account's name and password, from the URL `fleetbus users add` "
                    "prints (AMQP PLAIN)",
                },
                "certificate": {
                    "type": "X509",
                    "description": "`fleetbus users add NAME --cert`: a client certificate (CN = the "
                    "account's name) and the AMQP EXTERNAL mechanism, no password",
                },
            },
        },
    }
