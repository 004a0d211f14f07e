"""An outside client of `fleetbus api`: the package openapi-python-client generated from the served
OpenAPI document (``fleetbus_client``, on PYTHONPATH), run by ``.venv-peers/bin/python``, which
has none of fleetbus. It logs in, lists hazards and meets three refusals, and prints what it got
as one JSON object for ``test_generated_client.py`` to check.

    python generated_client_program.py BASE_URL OPERATOR GUEST < passwords.json
"""

from __future__ import annotations

import json
import sys
from typing import Any

from fleetbus_client import AuthenticatedClient, Client
from fleetbus_client.api.auth import login
from fleetbus_client.api.hazards import list_hazards
from fleetbus_client.models import BodyLogin, Problem, TokenOut


def described(answer: Any) -> dict[str, Any]:
    """The answer's generated type and, for a problem, its fields as the client parsed them."""
    shown: dict[str, Any] = {"type": type(answer).__name__}
    if isinstance(answer, Problem):
        shown.update(status=answer.status, title=answer.title, detail=answer.detail, instance=answer.instance)
        shown["errors"] = [{"loc": e.loc, "type": e.type_} for e in answer.errors or []]
    return shown


def main(base: str, operator: str, guest: str) -> None:
    passwords = json.load(sys.stdin)
    public = Client(base_url=base)

    def token_of(name: str) -> str:
        answer = login.sync(client=public, body=BodyLogin(username=name, password=passwords[name]))
        assert isinstance(answer, TokenOut), answer
        return answer.access_token

    as_operator = AuthenticatedClient(base_url=base, token=token_of(operator))
    as_guest = AuthenticatedClient(base_url=base, token=token_of(guest))
    hazards = list_hazards.sync(client=as_operator, limit=10)
    wrong = login.sync(client=public, body=BodyLogin(username=operator, password="not the password"))
    print(
        json.dumps(
            {
                "hazards": {"type": type(hazards).__name__, "count": len(hazards or [])},
                "wrong_password": described(wrong),
                "role_refused": described(list_hazards.sync(client=as_guest)),
                "bad_offset": described(list_hazards.sync(client=as_operator, offset=-1)),
            }
        )
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
