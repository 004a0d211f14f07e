"""The use cases each user may create missions of: set by an administrator through the HTTP API,
the command line or the console, and enforced by the missions service, so a mission of another
use case is refused with the same 403 and the same words through the API, the command line and
the console, changing nothing; an account none were set for may use every one."""

from __future__ import annotations

import pytest

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_HEADER, SESSION_COOKIE
from fleetbus.api.services.errors import Forbidden
from fleetbus.api.services.missions import use_case_refusal
from fleetbus.schemas.missions import MissionPlan
from fleetbus.schemas.roles import UserRole
from tests.api.support import PROBLEM_JSON, READY_PLAN, Api, problem, refusal, running_api
from tests.commands import fleetbus
from tests.support import Bus


def _console(api: Api, name: str) -> dict[str, str]:
    """Log ``name``'s browser in to the console (a minted session); its CSRF header."""
    api.client.get("/console/login")
    api.client.cookies.set(SESSION_COOKIE, api.session(name))
    return {CSRF_HEADER: api.client.cookies[CSRF_COOKIE]}


def _said(text: str) -> str:
    """A refusal as the command line prints it (Rich wraps long lines)."""
    return " ".join(text.split())


def test_a_use_case_the_client_is_not_allowed_is_refused_alike_everywhere(bus: Bus) -> None:
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("client1", UserRole.CLIENT)
        users, missions = api.service.repositories.users, api.service.repositories.missions
        shown = api.call("admin1", "GET", "/users/client1").json()
        assert shown["use_cases"] is None, "every use case until an admin restricts them"

        by_cli = fleetbus(bus, "users", "use-cases", "client1", "--allow", "survey")
        assert by_cli.returncode == 0, by_cli.stderr
        assert "client1 may create missions of: survey" in by_cli.stdout
        assert api.call("admin1", "GET", "/users/client1").json()["use_cases"] == ["survey"]
        client = api.run(lambda: users.get_user("client1"))
        assert client is not None
        detail = use_case_refusal(client, "hazard-response")
        assert detail is not None and "survey" in detail and "hazard-response" in detail

        # the application refuses; the API, the command line and the console say its words
        with pytest.raises(Forbidden) as refused:
            api.run(lambda: api.service.missions.create(client, "hazard-response", "x", MissionPlan()))
        assert refused.value.detail == detail
        body = {"use_case": "hazard-response", "title": "leak", "plan": READY_PLAN}
        by_api = api.call("client1", "POST", "/missions", json=body)
        assert refusal(by_api) == (403, PROBLEM_JSON, problem(403, detail, "/missions"))
        create = ("missions", "create", "--owner", "client1", "--title", "leak", "--use-case")
        by_cli = fleetbus(bus, *create, "hazard-response")
        assert by_cli.returncode == 1 and detail in _said(by_cli.stderr)
        csrf = _console(api, "client1")
        form = {"title": "leak", "use_case": "hazard-response", "geofence": "0 0\n50 0\n0 40"}
        by_console = api.client.post("/console/missions", data=form, headers=csrf)
        assert by_console.status_code == 403 and detail in by_console.text.replace("&#39;", "'")
        offered = api.client.get("/console/missions/new").text
        assert 'value="survey"' in offered and 'value="hazard-response"' not in offered
        assert api.run(missions.missions) == [], "nothing was created"

        # an allowed one goes through, from each
        allowed = api.call("client1", "POST", "/missions", json={**body, "use_case": "survey"})
        assert allowed.status_code == 201, allowed.text
        made = fleetbus(bus, *create, "survey")
        assert made.returncode == 0, made.stderr
        assert [(m.owner, m.use_case) for m in api.run(missions.missions)] == [("client1", "survey")] * 2

        # a blank title is refused alike by each (the rule is the service's)
        blank = ("missions", "create", "--owner", "client1", "--title", "   ", "--use-case", "survey")
        by_cli = fleetbus(bus, *blank)
        assert by_cli.returncode == 2 and "title: a mission's title has 1 to 200" in _said(by_cli.stderr)
        by_api = api.call("client1", "POST", "/missions", json={**body, "use_case": "survey", "title": "   "})
        assert by_api.status_code == 422 and "title" in by_api.json()["detail"], by_api.text
        assert len(api.run(missions.missions)) == 2, "nothing was created"

        # a use case that does not exist is refused alike, changing nothing; null allows every one
        unknown = api.call("admin1", "PUT", "/users/client1/use-cases", json={"use_cases": ["joyride"]})
        assert unknown.status_code == 422 and "joyride" in unknown.json()["detail"]
        by_cli = fleetbus(bus, "users", "use-cases", "client1", "--allow", "joyride")
        assert by_cli.returncode == 2 and unknown.json()["detail"] in _said(by_cli.stderr)
        assert api.call("admin1", "GET", "/users/client1").json()["use_cases"] == ["survey"]
        every = api.call("admin1", "PUT", "/users/client1/use-cases", json={"use_cases": None})
        assert every.status_code == 200 and every.json()["use_cases"] is None
        again = api.call("client1", "POST", "/missions", json=body)
        assert again.status_code == 201, "every use case again"

        document = api.client.get("/openapi.json").json()
        meaning = document["paths"]["/missions"]["post"]["responses"]["403"]["description"]
        assert "use case" in meaning
