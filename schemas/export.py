"""JSON Schema export of every message on the bus, and the AsyncAPI document of its channels."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fleetbus.schemas.asyncapi import asyncapi_document
from fleetbus.schemas.envelope import EVENT_ADAPTER, EVENT_MODELS


def json_schemas() -> dict[str, dict[str, Any]]:
    """One schema per event type, plus ``event`` for the discriminated union."""
    schemas: dict[str, dict[str, Any]] = {"event": EVENT_ADAPTER.json_schema()}
    for event_type, model in EVENT_MODELS.items():
        schemas[event_type.value] = model.model_json_schema()
    return schemas


def write_json_schemas(directory: Path, **asyncapi: Any) -> list[Path]:
    """``<type>.schema.json`` for every event type, plus ``asyncapi.json`` for the whole bus (made
    with ``asyncapi``: :func:`asyncapi_document`'s options)."""
    directory.mkdir(parents=True, exist_ok=True)
    documents = {f"{name}.schema.json": schema for name, schema in json_schemas().items()}
    documents["asyncapi.json"] = asyncapi_document(**asyncapi)
    written = []
    for filename, document in documents.items():
        path = directory / filename
        path.write_text(json.dumps(document, indent=2) + "\n")
        written.append(path)
    return written
