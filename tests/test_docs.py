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

from fleetbus.schemas.asyncapi import asyncapi_document

ROOT = Path(__file__).resolve().parent.parent
# AsyncAPI's own JSON Schema of the 2.6.0 specification, from the npm package @asyncapi/specs 6.11.1
# (schemas/2.6.0.json; Apache-2.0, see LICENSE and NOTICE beside it)
ASYNCAPI_SCHEMA = ROOT / "tests" / "data" / "asyncapi" / "asyncapi-2.6.0.schema.json"


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
