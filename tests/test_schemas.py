"""The message models: what is accepted, and errors that name the field."""

from __future__ import annotations

import json

import pytest

from fleetbus.schemas import EventType, SchemaError, build_event, encode_event, parse_event, validate_body
from fleetbus.schemas.envelope import NotJSONError, new_epoch
from fleetbus.schemas.export import json_schemas
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import event_routing_key, split_event_routing_key
from tests.factories import TABLE1_TIME, hazard, small_map, status

LOCALISED = {"localised": True, "pose": {"x": 1.0, "y": 2.0}}


def test_hazard_round_trips_exactly() -> None:
    event = build_event(EventType.HAZARD, "explorer1", new_epoch(), 7, hazard())
    again = parse_event(encode_event(event))
    assert again == event
    assert again.body.detected_at.isoformat() == TABLE1_TIME
    assert (again.body.pose.x, again.body.pose.y) == (2.66, 1.22)


def test_map_keeps_pgm_bytes_and_yaml_fields() -> None:
    data = small_map()
    event = parse_event(encode_event(build_event("map", "explorer1", new_epoch(), 0, data)))
    assert event.body.pgm.startswith(b"P5\n64 48\n255\n")
    assert event.body.metadata.origin == (2.1, 3.5, 0.0)
    assert event.body.metadata.free_thresh == 0.196


@pytest.mark.parametrize(
    ("event_type", "body", "field"),
    [
        ("hazard", {**hazard(), "pose": {"x": "north", "y": 1}}, "body.pose.x"),
        ("hazard", {**hazard(), "description": "  "}, "body.description"),
        ("hazard", {**hazard(), "pose": {"x": float("nan"), "y": 1}}, "body.pose.x"),
        ("localisation", {"pose": {"x": 1, "y": float("inf")}, "localised": True}, "body.pose.y"),
        ("status", {**status(), "battery_percent": 140}, "body.battery_percent"),
        ("map", {**small_map(), "pgm": "aGVsbG8="}, "body.pgm"),
        ("beacon", {"beacon_id": "b1", "rssi": -60, "colour": "red"}, "body.colour"),
    ],
)
def test_invalid_bodies_name_the_field(event_type: str, body: dict, field: str) -> None:
    with pytest.raises(SchemaError) as caught:
        validate_body(event_type, body)
    assert field in str(caught.value)


def test_not_json_is_its_own_error() -> None:
    with pytest.raises(NotJSONError):
        parse_event(b"\x00not json")


def test_envelope_rejects_unknown_type() -> None:
    raw = json.loads(encode_event(build_event("status", "explorer1", new_epoch(), 0, status())))
    raw["type"] = "teleport"
    with pytest.raises(SchemaError, match="type"):
        parse_event(json.dumps(raw))


@pytest.mark.parametrize("name", ["Explorer", "a", "x.y", "fleetbus-x", "amq1", "guest", "w*", ""])
def test_names_that_cannot_be_accounts(name: str) -> None:
    with pytest.raises(ValueError, match="invalid name"):
        validate_name(name)


def test_routing_keys() -> None:
    assert event_routing_key("warden1", "localisation") == "warden1.localisation"
    assert split_event_routing_key("warden1.localisation") == ("warden1", "localisation")
    with pytest.raises(ValueError):
        split_event_routing_key("nodot")


def test_every_type_has_a_json_schema() -> None:
    schemas = json_schemas()
    assert set(schemas) == {"event", *(t.value for t in EventType)}
    assert "body" in schemas["hazard"]["properties"]


@pytest.mark.parametrize(
    ("path", "value", "problem"),
    [
        (("seq",), "7", "localisation.seq: Input should be a valid integer"),
        (("seq",), 7.0, "localisation.seq: Input should be a valid integer"),
        (("body", "localised"), "yes", "localisation.body.localised: Input should be a valid boolean"),
        (("body", "localised"), 1, "localisation.body.localised: Input should be a valid boolean"),
        (("body", "pose", "x"), "1.5", "localisation.body.pose.x: Input should be a valid number"),
        (("sent_at",), 1767225600, "localisation.sent_at: Input should be a valid datetime"),
    ],
)
def test_a_message_is_read_as_the_asyncapi_document_types_it_not_converted(
    path: tuple[str, ...], value: object, problem: str
) -> None:
    """A string where the document has a number or a boolean is refused, naming the field: the
    gate must not read ``"localised": "yes"`` as localised, nor a consumer of the stream see it."""
    message = json.loads(encode_event(build_event(EventType.LOCALISATION, "r1", new_epoch(), 7, LOCALISED)))
    parse_event(json.dumps(message))  # as the client sends it
    inner = message
    for key in path[:-1]:
        inner = inner[key]
    inner[path[-1]] = value
    with pytest.raises(SchemaError) as refused:
        parse_event(json.dumps(message))
    assert str(refused.value) == problem
