"""The hazard gate's team over HTTP, with the real worker, broker and both stores: ``GET /team``,
a warden taken out of service and back by an operator (on record), and ``DELETE /users/{name}``
taking a warden out of the team in the same operation."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from fleetbus.broker.accounts import Account, Role
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.api.support import Api, running_api_on_each_store
from tests.api.test_channels import robot_url
from tests.factories import hazard
from tests.support import Bus, wait_for


@pytest.fixture(params=["sqlite", "mongodb"])
def api(request: pytest.FixtureRequest, bus: Bus) -> Iterator[Api]:
    with running_api_on_each_store(request, bus) as running:
        running.user("admin1", UserRole.ADMIN)
        running.user("super1", UserRole.SUPERVISOR)
        running.user("oper1", UserRole.OPERATOR)
        for name, kind in (
            ("explorer1", RobotKind.EXPLORER),
            ("warden1", RobotKind.WARDEN),
            ("warden2", RobotKind.WARDEN),
        ):
            running.user(name, UserRole.ROBOT, kind)
        yield running


def robot(api: Api, name: str) -> RobotClient:
    return api.bus.robot(Account(name, Role.ROBOT, robot_url(api, name)))


def held(api: Api) -> list[str]:
    return [h.state.value for h in api.run(lambda: api.service.repositories.hazards.open_hazards("default"))]


def test_an_operator_takes_a_warden_out_of_service_and_back_on_record(api: Api) -> None:
    explorer, warden1, warden2 = (robot(api, name) for name in ("explorer1", "warden1", "warden2"))
    with api.bus.worker():
        warden1.publish("localisation", {"localised": True})
        sent = explorer.publish("hazard", hazard(0))
        wait_for(lambda: held(api) == ["held"], what="the hazard held")
        team = api.call("oper1", "GET", "/team").json()
        assert [(r["name"], r["kind"], r["counts_for_gate"]) for r in team["robots"]] == [
            ("explorer1", "explorer", False),
            ("warden1", "warden", True),
            ("warden2", "warden", True),
        ]
        assert team["gate"] == {
            "open": False,
            "announces_to": ["warden1", "warden2"],
            "closed_because": "waiting for warden2: not localised, last seen never",
        }
        [warden1_row] = [r for r in team["robots"] if r["name"] == "warden1"]
        assert warden1_row["last_seen"] is not None and not warden1_row["stale"] and warden1_row["localised"]

        out = api.call("oper1", "POST", "/team/warden2/out")
        assert out.status_code == 200, out.text
        assert (out.json()["in_service"], out.json()["service_changed_by"]) == (False, "oper1")
        assert [n.event for n in warden1.receive(1, timeout=30)] == [sent]
        wait_for(lambda: held(api) == ["announced"], what="announced without warden2")

        back = api.call("super1", "POST", "/team/warden2/in")
        assert back.status_code == 200, back.text
        assert (back.json()["in_service"], back.json()["service_changed_by"]) == (True, "super1")
        [caught_up] = warden2.receive(1, timeout=30)
        assert caught_up.event == sent and caught_up.hazard_state == "announced"

        refused = api.call("oper1", "POST", "/team/explorer1/out")
        assert (refused.status_code, refused.json()["detail"]) == (
            422,
            "explorer1 is an explorer: only wardens are taken out of service",
        )
        assert api.call("oper1", "POST", "/team/nobody/out").status_code == 404


def test_deleting_a_warden_takes_it_out_of_the_team_in_the_same_operation(api: Api) -> None:
    explorer, warden1 = robot(api, "explorer1"), robot(api, "warden1")
    with api.bus.worker():
        warden1.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(0)), ("hazard", hazard(1))])
        wait_for(lambda: held(api) == ["held", "held"], what="held for warden2")
        assert api.call("admin1", "DELETE", "/users/warden2").status_code == 204
        names = [r["name"] for r in api.call("super1", "GET", "/team").json()["robots"]]
        assert names == ["explorer1", "warden1"]
        assert [n.event for n in warden1.receive(2, timeout=30)] == sent
        wait_for(lambda: held(api) == ["announced", "announced"], what="announced")
