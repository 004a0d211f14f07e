"""MkDocs hook: the reference and performance pages, generated from the code at every build.

mkdocs.yml names this file under ``hooks:``; ``bash scripts/docs`` (or ``mkdocs build``) runs it.
Nothing is written into docs/: each page is added to the build as a generated file. (The command
line reference, docs/reference/cli.md, is kept in the repository instead, so that the README's
link to it works in a checkout: ``python -m fleetbus.cli.reference --update`` writes it, and a
test fails while it differs from the parser.)

- reference/http-api.md: FastAPI's OpenAPI document rendered by essentials-openapi (the renderer of
  neoteroi's OAD plugin, called directly: the plugin reads a file from disk, and the document is
  made here in memory), and openapi.json beside it;
- reference/messages.md: the JSON Schema of every event type, as tables, and the schema files;
- reference/asyncapi.md: the AsyncAPI document (the server, the event properties, the channels),
  and asyncapi.json;
- performance/runs.md: every benchmark suite report, committed under docs/performance/runs/ or
  left by ``python -m bench`` in bench/results/, newest first.

The messages and channels pages are written here, not by a plugin: the plugins that render JSON
Schema or AsyncAPI either need a browser bundle fetched from the network or do not handle
pydantic's ``$defs``; a table per model is a few lines.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parent.parent
RUNS_FOLDERS = (ROOT / "docs" / "performance" / "runs", ROOT / "bench" / "results")
GENERATED_NOTE = "<!-- generated at build time by scripts/docs_hooks.py: edit the code, not this page -->\n"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    pages = {
        "reference/http-api.md": http_api_page(),
        "reference/messages.md": messages_page(),
        "reference/asyncapi.md": asyncapi_page(),
        "performance/runs.md": runs_page(),
    }
    for path, text in pages.items():
        files.append(File.generated(config, path, content=GENERATED_NOTE + text))
    for path, document in downloads().items():
        files.append(File.generated(config, path, content=json.dumps(document, indent=2) + "\n"))
    return files


# --- the HTTP API ---------------------------------------------------------------------------------


def openapi_document() -> dict[str, Any]:
    from fleetbus.api.app import create_app
    from fleetbus.settings import load_settings

    # no broker is asked anything while the document is made; the URLs only fill the app's config
    return create_app(load_settings({}), "amqp://localhost/", "http://localhost:15672/").openapi()


def http_api_page() -> str:
    from openapidocs.mk.v3 import OpenAPIV3DocumentationHandler

    rendered = OpenAPIV3DocumentationHandler(openapi_document(), style="MKDOCS").write()
    rendered = rendered.split("-->", 1)[1] if rendered.lstrip().startswith("<!--") else rendered
    rest = rendered.lstrip().partition("\n")[2]  # its own title; the page has one of its own
    return (
        "# HTTP API reference\n\n"
        "Every route of `fleetbus api`, from the OpenAPI document the service serves at "
        "`/openapi.json` ([download it](openapi.json), or `fleetbus api openapi FILE`). Routes say "
        "which roles may call them (`x-roles`). Log in with `POST /auth/token` and send the token "
        "as `Authorization: Bearer <token>`.\n\n"
        + rest.replace("\n# ", "\n## ").replace("<hr />", REFUSALS + "<hr />", 1)
    )


REFUSALS = """

## Refusals

The refusals are problems as the description above says; a request that is not valid, for one:

```json
{"type": "about:blank", "title": "Unprocessable Entity", "status": 422,
 "detail": "query.offset: Input should be greater than or equal to 0", "instance": "/hazards",
 "errors": [{"loc": ["query", "offset"], "msg": "Input should be greater than or equal to 0",
             "type": "greater_than_equal"}]}
```

Each operation below lists exactly the statuses it can answer with; a 401 carries
`WWW-Authenticate: Bearer`, a 429 `Retry-After`. More examples: [Refusals in the
guide](../guides/service-layer.md#refusals-problem-details).

## Checking the service against this document

The test suite runs schemathesis against the service with a token of each role. To run it
yourself, from the checkout's root with the outside peers installed
(`FLEETBUS_WITH_PEERS=1 bash scripts/setup`), `fleetbus api` on port 8000 and `TOKEN` holding an
access token ([the guide](../guides/service-layer.md#checking-the-api-against-its-document) logs
in for it):

```sh
.venv-peers/bin/schemathesis --config-file tests/peers/schemathesis.toml run \\
    http://127.0.0.1:8000/openapi.json --header "Authorization: Bearer $TOKEN" \\
    --checks CHECKS \\
    --phases examples,coverage,fuzzing --seed 20261127 --max-examples 4
```

""".replace(
    "CHECKS",
    "not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance,"
    "negative_data_rejection",
)


# --- messages and channels -----------------------------------------------------------------------


def downloads() -> dict[str, dict[str, Any]]:
    from fleetbus.schemas.asyncapi import asyncapi_document
    from fleetbus.schemas.export import json_schemas

    files = {f"reference/schemas/{name}.schema.json": schema for name, schema in json_schemas().items()}
    files["reference/asyncapi.json"] = asyncapi_document()
    files["reference/openapi.json"] = openapi_document()
    return files


def _type_of(prop: dict[str, Any]) -> str:
    if "$ref" in prop:
        name = prop["$ref"].rsplit("/", 1)[1]
        return f"[{name}](#{name.lower()})"
    if "anyOf" in prop or "oneOf" in prop:
        return " or ".join(_type_of(option) for option in prop.get("anyOf", prop.get("oneOf")))
    if "const" in prop:
        return f"`{json.dumps(prop['const'])}`"
    if "enum" in prop:
        return "one of " + ", ".join(f"`{json.dumps(value)}`" for value in prop["enum"])
    kind = prop.get("type", "any")
    if kind == "array":
        return f"array of {_type_of(prop.get('items', {}))}"
    if kind == "null":
        return "null"
    return f"{kind} ({prop['format']})" if "format" in prop else str(kind)


def _constraints(prop: dict[str, Any]) -> str:
    words = {
        "minimum": "≥ {}",
        "exclusiveMinimum": "> {}",
        "maximum": "≤ {}",
        "exclusiveMaximum": "< {}",
        "minLength": "length ≥ {}",
        "maxLength": "length ≤ {}",
        "minItems": "items ≥ {}",
        "maxItems": "items ≤ {}",
        "pattern": "matches `{}`",
    }
    found = [text.format(prop[key]) for key, text in words.items() if key in prop]
    for option in prop.get("anyOf", []):
        found += [text.format(option[key]) for key, text in words.items() if key in option]
    if "default" in prop:
        found.append(f"default `{json.dumps(prop['default'])}`")
    return "; ".join(found)


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def model_table(name: str, schema: dict[str, Any]) -> list[str]:
    lines = [f"### {name}", ""]
    if schema.get("description"):
        lines += [_escape(schema["description"]), ""]
    if schema.get("additionalProperties") is False:
        lines += ["Unknown fields are refused.", ""]
    required = set(schema.get("required", []))
    lines += ["| field | type | required | constraints | meaning |", "| --- | --- | --- | --- | --- |"]
    for field, prop in schema.get("properties", {}).items():
        lines.append(
            f"| `{field}` | {_escape(_type_of(prop))} | {'yes' if field in required else ''} | "
            f"{_escape(_constraints(prop))} | {_escape(prop.get('description', ''))} |"
        )
    return [*lines, ""]


def messages_page() -> str:
    from fleetbus.schemas.export import json_schemas

    schemas = json_schemas()
    lines = [
        "# Message schemas",
        "",
        "Every event a robot publishes travels in one envelope with a typed `body`. These tables are "
        "generated from the pydantic models in `fleetbus.schemas`; the same schemas as JSON Schema "
        "files: "
        + ", ".join(f"[{name}](schemas/{name}.schema.json)" for name in schemas)
        + " (`fleetbus schemas DIR` writes them too). The channels they travel on are in the "
        "[AsyncAPI reference](asyncapi.md).",
        "",
    ]
    seen: set[str] = set()
    for name, schema in schemas.items():
        if name == "event":
            continue
        lines += [f"## `{name}`", ""]
        lines += model_table(schema.get("title", name), schema)
        for definition, sub in schema.get("$defs", {}).items():
            if definition not in seen:
                seen.add(definition)
                lines += model_table(definition, sub)
    return "\n".join(lines)


def asyncapi_page() -> str:
    from fleetbus.schemas.asyncapi import asyncapi_document

    document = asyncapi_document()
    [server] = document["servers"].values()
    event = document["components"]["messageTraits"]["event"]
    lines = [
        "# AsyncAPI: the contract",
        "",
        f"The bus described as an AsyncAPI {document['asyncapi']} document, generated from the "
        "models and the routing constants in `fleetbus.schemas`: [asyncapi.json](asyncapi.json) "
        "(`fleetbus schemas DIR` writes it too, its server the broker `fleetbus users add` hands out "
        "there). It is the contract for a robot written in any language ([A robot in another "
        "language](../guides/robot-client.md#a-robot-in-another-language)); a test validates it "
        "against the official AsyncAPI JSON Schema of its version and its AMQP bindings, and a "
        "Node.js robot built from it alone runs in CI.",
        "",
        document["info"]["description"],
        "",
        "## Connecting",
        "",
        f"`{server['protocol']}` (AMQP {server['protocolVersion']}), `{server['url']}`. "
        + server["description"],
        "",
        "## What every event message carries",
        "",
        _escape(event["description"]),
        "",
        "| AMQP property | required | value | meaning |",
        "| --- | --- | --- | --- |",
    ]
    properties = event["x-amqp-properties"]
    for name, prop in properties["properties"].items():
        value = f"`{json.dumps(prop['const'])}`" if "const" in prop else ""
        required = "yes" if name in properties["required"] else ""
        lines.append(f"| `{name}` | {required} | {value} | {_escape(prop.get('description', ''))} |")
    lines += [
        "",
        "The body fields each type requires are the `required` lists of its payload schema "
        "([Message schemas](messages.md)).",
        "",
        "## Channels",
        "",
        "| channel | operation | AMQP | messages |",
        "| --- | --- | --- | --- |",
    ]
    for name, channel in document["channels"].items():
        operation_kind = "publish" if "publish" in channel else "subscribe"
        operation = channel[operation_kind]
        message = operation["message"]
        options = message.get("oneOf", [message])
        names = [
            option["$ref"].rsplit("/", 1)[1] if "$ref" in option else option.get("name", "")
            for option in options
        ]
        amqp = channel.get("bindings", {}).get("amqp", {})
        where = (
            f"exchange `{amqp['exchange']['name']}` ({amqp['exchange']['type']})"
            if amqp.get("is") == "routingKey"
            else f"queue `{amqp.get('queue', {}).get('name', name)}`"
        )
        lines.append(
            f"| `{name}` | {operation_kind} (`{operation['operationId']}`) | {where} | "
            + ", ".join(f"`{n}`" for n in names)
            + " |"
        )
    lines += ["", "## What each channel carries", ""]
    for name, channel in document["channels"].items():
        lines += [f"### `{name}`", "", channel["description"], ""]
    return "\n".join(lines)


# --- performance ---------------------------------------------------------------------------------


def runs_page() -> str:
    reports = sorted(
        (path for folder in RUNS_FOLDERS if folder.is_dir() for path in folder.glob("suite-*.md")),
        key=lambda path: path.name,
        reverse=True,
    )
    lines = [
        "# Benchmark runs",
        "",
        "Every report of the benchmark suite (`.venv/bin/python -m bench`), newest first: the "
        "runs kept in the repository (`docs/performance/runs/`) and any left on this machine in "
        "`bench/results/`. Each says when, on which machine and under what load it ran; compare "
        "runs by their ratios and raw broker hops, not by their milliseconds.",
        "",
    ]
    if not reports:
        lines.append("No report found: run `.venv/bin/python -m bench` first.")
    for report in reports:
        text = report.read_text()
        first, _, rest = text.partition("\n")
        lines += [f"## {first.split(',', 1)[1].split('(')[0].strip() or report.stem}", "", first, rest, ""]
    return "\n".join(lines)
