"""Schemathesis hooks (loaded through ``tests/peers/schemathesis.toml``): the edge values of every
numeric parameter of the OpenAPI document, sent as explicit examples of each operation.

For each integer or number parameter in the path or the query, and each of :data:`EDGES`, one
example: the operation's first example (``fill-missing`` makes one from the schema when the
document has none) with that parameter set to the value. Schemathesis itself then decides, from
the document, whether the example is valid (the API must accept it without a server error) or not
(the API must refuse it with a documented 4xx), as it does for the examples it generates.

This file runs inside schemathesis (``.venv-peers``), never inside fleetbus's own venv.
"""

from __future__ import annotations

import sys
from typing import Any

import schemathesis
from schemathesis.core.parameters import ParameterLocation
from schemathesis.generation.meta import (
    CaseMetadata,
    ComponentInfo,
    ExamplesPhaseData,
    GenerationInfo,
    PhaseInfo,
    TestPhase,
)
from schemathesis.generation.modes import GenerationMode

#: 0, -1, past the largest signed 64-bit integer, near the largest double, the smallest positive double
EDGES: tuple[int | float, ...] = (0, -1, 2**63, 1e308, sys.float_info.min * sys.float_info.epsilon)
LOCATIONS = (ParameterLocation.PATH, ParameterLocation.QUERY)


def _types(schema: Any) -> set[str]:
    """The JSON types a parameter's schema admits (through ``anyOf``/``oneOf``, as FastAPI writes
    an optional parameter)."""
    if not isinstance(schema, dict):
        return set()
    kind = schema.get("type")
    found = set(kind) if isinstance(kind, list) else {kind} if kind else set()
    for key in ("anyOf", "oneOf", "allOf"):
        for option in schema.get(key, []):
            found |= _types(option)
    return found


def numeric_parameters(operation: Any) -> list[tuple[ParameterLocation, str]]:
    return [
        (location, parameter.name)
        for location in LOCATIONS
        for parameter in getattr(operation, location.container_name)
        if _types(parameter.definition.get("schema")) & {"integer", "number"}
    ]


def edge_case(operation: Any, base: Any, location: ParameterLocation, name: str, value: float) -> Any:
    meta = CaseMetadata(
        generation=GenerationInfo(time=0.0, mode=GenerationMode.POSITIVE),
        components={where: ComponentInfo(mode=GenerationMode.POSITIVE) for where in LOCATIONS},
        phase=PhaseInfo(
            name=TestPhase.EXAMPLES,
            data=ExamplesPhaseData(
                description=f"edge value {value!r} of `{name}`",
                parameter=name,
                parameter_location=location,
                location=None,
            ),
        ),
    )
    case = operation.Case(
        path_parameters=dict(base.path_parameters),
        query=dict(base.query),
        body=base.body,
        media_type=base.media_type,
        _meta=meta,
    )
    # set after creation: schemathesis sees the change and checks the value against the
    # document, marking the example negative when the value is outside the parameter's schema
    setattr(case, location.container_name, {**getattr(case, location.container_name), name: value})
    return case


@schemathesis.hook
def before_add_examples(context: Any, examples: list[Any]) -> None:
    operation = context.operation
    if operation is None or not examples:
        return
    base = examples[0]
    examples.extend(
        edge_case(operation, base, location, name, value)
        for location, name in numeric_parameters(operation)
        for value in EDGES
    )
