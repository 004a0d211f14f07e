"""The service-layer guide's table of endpoints and the roles they admit is the API's: every
operation of the OpenAPI document is in it, with the roles of its ``x-roles``, and nothing else."""

from __future__ import annotations

import re
from pathlib import Path

from fleetbus.schemas.roles import UserRole
from scripts.docs_hooks import openapi_document

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "service-layer.md"
TABLE_INTRO = "The endpoints and the roles they admit"
ANYONE = frozenset({"anyone", "anyone holding the token"})
#: Operations without ``x-roles``: the table says who may call them in words.
PUBLIC = "public"


def _route(path: str) -> str:
    """A path with its parameters unnamed: ``/missions/{id}`` and ``/missions/{mission_id}`` are one."""
    return re.sub(r"\{[^}]*\}", "{}", path)


def _roles(cell: str) -> frozenset[str]:
    words = re.sub(r"\([^)]*\)", "", cell).strip()
    if words in ANYONE:
        return frozenset({PUBLIC})
    if words == "every role but inactive":
        return frozenset(role.value for role in UserRole if role is not UserRole.INACTIVE)
    roles = frozenset(word.strip() for word in words.split(","))
    unknown = roles - {role.value for role in UserRole}
    assert not unknown, f"the guide's roles table names no role {sorted(unknown)} in {cell!r}"
    return roles


def guide_table() -> dict[tuple[str, str], frozenset[str]]:
    text = GUIDE.read_text()
    lines = text[text.index(TABLE_INTRO) :].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| endpoint |"))
    table: dict[tuple[str, str], frozenset[str]] = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        endpoints, roles = (cell.strip() for cell in line.strip("|").split("|"))
        for method, path in re.findall(r"`(GET|POST|PUT|PATCH|DELETE) ([^`]+)`", endpoints):
            assert (method, _route(path)) not in table, f"{method} {path} is in the guide's table twice"
            table[(method, _route(path))] = _roles(roles)
    return table


def test_the_guides_roles_table_is_the_openapi_documents() -> None:
    document = {
        (method.upper(), _route(path)): frozenset(operation.get("x-roles") or {PUBLIC})
        for path, operations in openapi_document()["paths"].items()
        for method, operation in operations.items()
    }
    table = guide_table()
    assert sorted(set(document) - set(table)) == [], "operations the guide's table leaves out"
    assert sorted(set(table) - set(document)) == [], "the guide's table names operations the API has not"
    differ = {op: (sorted(table[op]), sorted(document[op])) for op in document if table[op] != document[op]}
    assert differ == {}, "(the guide's roles, the document's)"
