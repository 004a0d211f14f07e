"""The documentation: the AsyncAPI document is valid AsyncAPI, and the site builds without a warning."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from referencing import Registry, Resource

from fleetbus.schemas.asyncapi import asyncapi_document
from fleetbus.schemas.services import METHODS
from fleetbus.settings import Settings
from fleetbus.workers.beacons import beacon_services
from fleetbus.workers.maps import map_services
from fleetbus.workers.services import hazard_services

ROOT = Path(__file__).resolve().parent.parent
# AsyncAPI's own JSON Schema of the 2.6.0 specification, from the npm package @asyncapi/specs 6.11.1
# (schemas/2.6.0.json; Apache-2.0, see LICENSE and NOTICE beside it)
ASYNCAPI_SCHEMA = ROOT / "tests" / "data" / "asyncapi" / "asyncapi-2.6.0.schema.json"
# its AMQP bindings' JSON Schemas, from the same package (bindings/amqp/0.3.0/*.json, and the
# definitions/3.0.0/specificationExtension.json they refer to)
AMQP_BINDINGS = ROOT / "tests" / "data" / "asyncapi" / "bindings"


@pytest.fixture(scope="module")
def asyncapi_validator() -> jsonschema.protocols.Validator:
    schema = json.loads(ASYNCAPI_SCHEMA.read_text())
    validator_class = jsonschema.validators.validator_for(schema)
    validator_class.check_schema(schema)
    return validator_class(schema)


def _errors(validator: jsonschema.protocols.Validator, document: dict[str, Any]) -> list[str]:
    return [
        f"{'/'.join(map(str, error.absolute_path))}: {error.message[:200]}"
        for error in validator.iter_errors(document)
    ]


def test_the_asyncapi_document_is_valid_against_the_official_schema_of_its_version(
    asyncapi_validator: jsonschema.protocols.Validator,
) -> None:
    document = asyncapi_document()
    assert document["asyncapi"] == "2.6.0"  # the vendored schema is this version's
    assert _errors(asyncapi_validator, document) == []


@pytest.fixture(scope="module")
def binding_validators() -> dict[str, jsonschema.protocols.Validator]:
    """The official AMQP binding schemas (0.3.0) of channels, operations and messages."""
    extension = json.loads((AMQP_BINDINGS / "specificationExtension-3.0.0.json").read_text())
    registry = Registry().with_resource(extension["$id"], Resource.from_contents(extension))
    validators = {}
    for kind in ("channel", "operation", "message"):
        schema = json.loads((AMQP_BINDINGS / "amqp" / "0.3.0" / f"{kind}.json").read_text())
        validator_class = jsonschema.validators.validator_for(schema)
        validator_class.check_schema(schema)
        validators[kind] = validator_class(schema, registry=registry)
    return validators


def _amqp_bindings(document: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    """Every AMQP binding of the document: (kind, where, binding)."""
    found: list[tuple[str, str, dict[str, Any]]] = []

    def message(where: str, item: dict[str, Any]) -> None:
        for option in item.get("oneOf", [item]):
            if "amqp" in option.get("bindings", {}):
                found.append(("message", where, option["bindings"]["amqp"]))

    for name, channel in document["channels"].items():
        found.append(("channel", name, channel["bindings"]["amqp"]))
        for kind in ("publish", "subscribe"):
            if kind in channel:
                if "amqp" in channel[kind].get("bindings", {}):
                    found.append(("operation", f"{name} {kind}", channel[kind]["bindings"]["amqp"]))
                message(f"{name} {kind}", channel[kind]["message"])
    for name, item in document["components"]["messages"].items():
        message(name, item)
    return found


def test_every_amqp_binding_is_valid_against_the_official_binding_schemas(
    binding_validators: dict[str, jsonschema.protocols.Validator],
) -> None:
    found = _amqp_bindings(asyncapi_document())
    assert {kind for kind, _, _ in found} == {"channel", "operation", "message"}
    problems = [
        f"{kind} {where}: {error}"
        for kind, where, binding in found
        for error in _errors(binding_validators[kind], binding)
    ]
    assert problems == []
    assert {binding["bindingVersion"] for _, _, binding in found} == {"0.3.0"}
    broken = {"is": "routingKey", "exchange": {"name": "x", "type": "fanout-ish"}, "bindingVersion": "0.3.0"}
    assert _errors(binding_validators["channel"], broken), "the schemas do catch a wrong binding"


def test_the_documented_services_are_the_workers_own() -> None:
    handlers = {
        **hazard_services(None, None),  # type: ignore[arg-type]
        **beacon_services(None, None, Settings().beacon_window_max),  # type: ignore[arg-type]
        **map_services(None),  # type: ignore[arg-type]
    }
    assert [method.name for method in METHODS] == list(handlers)
    channels = asyncapi_document()["channels"]
    assert all(f"{{robot}}.{name}" in channels for name in handlers)


def test_the_server_is_the_one_robots_are_handed() -> None:
    [server] = asyncapi_document(broker_url="amqps://broker.example:5999/?cacertfile=/ca.pem")[
        "servers"
    ].values()
    assert (server["protocol"], server["url"]) == ("amqps", "{host}:{port}")
    assert {name: v["default"] for name, v in server["variables"].items()} == {
        "host": "broker.example",
        "port": "5999",
    }
    [default] = asyncapi_document()["servers"].values()
    assert (default["protocol"], default["variables"]["port"]["default"]) == ("amqps", "5671")
    assert "cacertfile" in default["description"], "the note that other clients ignore it"


def test_the_validation_finds_what_asyncapi_refuses(
    asyncapi_validator: jsonschema.protocols.Validator,
) -> None:
    """pydantic writes OpenAPI's discriminator object; AsyncAPI 2.6 wants the property name alone."""
    document = copy.deepcopy(asyncapi_document())
    event = document["components"]["schemas"]["Notification"]["properties"]["event"]
    assert event["discriminator"] == "type"
    event["discriminator"] = {"propertyName": "type", "mapping": {}}
    del document["channels"]["notify.{topic}"]["subscribe"]["operationId"]
    document["channels"]["notify.{topic}"]["subscribe"]["unknown"] = True
    errors = _errors(asyncapi_validator, document)
    assert any("discriminator" in error for error in errors), errors
    assert any("unknown" in error for error in errors), errors


def test_the_documentation_site_builds_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict``: every generated page is made and every link inside the site resolves."""
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=240,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert built.returncode == 0, built.stderr[-4000:]
    site = tmp_path / "site"
    for page in ("reference/cli", "reference/http-api", "reference/messages", "reference/asyncapi"):
        assert (site / page / "index.html").is_file(), page
    assert "fleetbus worker" in (site / "reference" / "cli" / "index.html").read_text()
    assert json.loads((site / "reference" / "asyncapi.json").read_text()) == asyncapi_document()


def test_the_command_line_reference_is_the_parsers() -> None:
    """docs/reference/cli.md is kept in the repository (the README links it): it must be what the
    console script's parser says now."""
    from fleetbus.cli.reference import UPDATE, reference_page

    page = ROOT / "docs" / "reference" / "cli.md"
    assert page.read_text() == reference_page(), f"docs/reference/cli.md is out of date: run `{UPDATE}`"
