"""A mission's discussion over HTTP and from the command line: the same rule and the same outcome
for the same request (who may comment, the text's bound, a mission that does not exist), the
refusals documented in the OpenAPI document, the thread read back the same both ways."""

from __future__ import annotations

import json
from datetime import datetime
from typing import Any

from fleetbus.api.services.mission_comments import COMMENT_MAX
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.api.support import PROBLEM_JSON, Api, problem, refusal, running_api
from tests.commands import fleetbus
from tests.support import Bus

USERS = {
    "client1": UserRole.CLIENT,
    "client2": UserRole.CLIENT,
    "planner1": UserRole.PLANNER,
    "super1": UserRole.SUPERVISOR,
    "oper1": UserRole.OPERATOR,
    "admin1": UserRole.ADMIN,
    "visitor1": UserRole.GUEST,
}


def same(comment: dict[str, Any]) -> tuple[Any, ...]:
    """A comment as read over HTTP or from the shell, its time as a moment."""
    at = datetime.fromisoformat(comment["at"].replace("Z", "+00:00"))
    return (comment["number"], comment["mission_id"], comment["author"], comment["role"], comment["text"], at)


def count(api: Api, mission_id: str) -> int:
    return api.run(lambda: api.service.repositories.comments.count_comments(mission_id))


def test_the_api_and_the_command_line_comment_by_one_rule_with_the_same_outcome(bus: Bus) -> None:
    with running_api(bus) as api:
        for name, role in USERS.items():
            api.user(name, role)
        api.user("explorer1", UserRole.ROBOT, RobotKind.EXPLORER)
        api.user("new1", UserRole.INACTIVE)
        mission = api.mission().mission_id  # client1's
        path = f"/missions/{mission}/comments"

        # the same refusals (the guest's by the route's role check over HTTP, by the service's
        # rule from the shell: both name the role), nothing stored by either
        refused = [
            ("visitor1", "text", 403, "role guest may not"),
            ("explorer1", "text", 403, "role robot may not"),
            ("new1", "text", 403, "role inactive may not"),
            ("client2", "text", 403, f"mission {mission} belongs to another client"),
            ("oper1", "   \n ", 422, "the comment is empty"),
            ("oper1", "x" * (COMMENT_MAX + 1), 422, f"the comment has {COMMENT_MAX + 1} characters; at most"),
        ]
        for who, text, status, detail in refused:
            reply = api.call(who, "POST", path, json={"text": text})
            assert reply.status_code == status and detail in reply.json()["detail"], (who, reply.text)
            assert reply.headers["content-type"] == PROBLEM_JSON
            ran = fleetbus(bus, "missions", "comment", mission, text, "--as", who)
            # bad input is a usage error (2), as for every command; a refusal of the caller, 1
            assert ran.returncode == (2 if status == 422 else 1), (who, ran)
            assert detail in " ".join(ran.stderr.split()), (who, ran)
        # the shell comments as an account of the registry, never as a name of its own
        ran = fleetbus(bus, "missions", "comment", mission, "text", "--as", "nobody")
        assert ran.returncode == 1 and "no account 'nobody'" in ran.stderr, ran
        assert count(api, mission) == 0
        unknown = api.call("oper1", "POST", "/missions/m-404/comments", json={"text": "hello"})
        assert refusal(unknown) == (
            404,
            PROBLEM_JSON,
            problem(404, "no mission 'm-404'", "/missions/m-404/comments"),
        )
        ran = fleetbus(bus, "missions", "comment", "m-404", "hello", "--as", "oper1")
        assert ran.returncode == 1 and "no mission 'm-404'" in ran.stderr

        # every commenting role, alternately over HTTP and from the shell
        said = []
        for n, who in enumerate(("client1", "planner1", "super1", "oper1", "admin1")):
            text = f"{who} says <b>{n}</b>\nsecond line"
            if n % 2:
                made = fleetbus(bus, "missions", "comment", mission, text, "--as", who, "--json")
                assert made.returncode == 0, made
                comment = json.loads(made.stdout)
            else:
                reply = api.call(who, "POST", path, json={"text": text})
                assert reply.status_code == 201, reply.text
                comment = reply.json()
            said.append((who, USERS[who].value, text))
            assert (comment["author"], comment["role"], comment["text"]) == said[-1]

        over_http = api.call("visitor1", "GET", path).json()  # a guest reads
        assert [(c["author"], c["role"], c["text"]) for c in over_http] == said
        assert all(c["at"].endswith(("Z", "+00:00")) for c in over_http), "UTC"
        shell = fleetbus(bus, "missions", "comments", mission, "--json")
        assert shell.returncode == 0
        assert [same(json.loads(line)) for line in shell.stdout.splitlines()] == [same(c) for c in over_http]
        assert api.call("oper1", "GET", f"{path}?limit=2").json() == over_http[-2:]
        assert api.call("client2", "GET", path).status_code == 403, "another client's mission"
        table = fleetbus(bus, "missions", "comments", mission)
        assert "planner1" in table.stdout and "supervisor" in table.stdout

        operation = api.client.get("/openapi.json").json()["paths"]["/missions/{mission_id}/comments"]["post"]
        assert {"401", "403", "404", "422", "503"} <= set(operation["responses"])
        assert operation["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith("CommentIn")
