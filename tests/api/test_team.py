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
from tests.test_cli import fleetbus


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
        # the command line asks the same service: the same refusal, as its error (bad input: 2)
        cli = fleetbus(api.bus, "team", "out", "explorer1", "--by", "oper1")
        assert (cli.returncode, cli.stderr) == (2, f"error: {refused.json()['detail']}\n")


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


def test_an_operator_claims_and_clears_for_a_warden_who_is_told_and_the_rules_stay_the_wardens(
    api: Api,
) -> None:
    explorer, warden1, warden2 = (robot(api, name) for name in ("explorer1", "warden1", "warden2"))
    with api.bus.worker():
        for warden in (warden1, warden2):
            warden.publish("localisation", {"localised": True})
        sent = explorer.publish("hazard", hazard(0))
        assert [n.event for n in warden1.receive(1, timeout=30)] == [sent]
        wait_for(lambda: held(api) == ["announced"], what="the hazard announced")

        claimed = api.call("oper1", "POST", "/hazards/default/1/claim", json={"warden": "warden1"})
        assert claimed.status_code == 200, claimed.text
        assert claimed.json()["hazard"]["state"] == "claimed" and claimed.json()["warden_told"]
        assert claimed.json()["hazard"]["claimed_by"] == "warden1"
        [note] = warden1.receive(1, timeout=30)
        assert (note.event, note.hazard_state, note.claimed_by) == (sent, "claimed", "warden1")

        not_holder = api.call("super1", "POST", "/hazards/default/1/cleared", json={"warden": "warden2"})
        assert not_holder.status_code == 409 and "warden1" in not_holder.json()["detail"], not_holder.text
        for step in ("reached", "cleared"):
            done = api.call("super1", "POST", f"/hazards/default/1/{step}", json={"warden": "warden1"})
            assert done.json()["hazard"]["state"] == step, done.text
        assert [n.hazard_state for n in warden1.receive(2, timeout=30)] == ["reached", "cleared"]

        listed = api.call("oper1", "GET", "/hazards", params={"state": "cleared"}).json()
        assert [(h["hazard_id"], h["claimed_by"], h["robot_id"]) for h in listed] == [
            (1, "warden1", "explorer1")
        ]
        admin = api.call("admin1", "POST", "/hazards/default/1/claim", json={"warden": "warden1"})
        assert admin.status_code == 403, "administrators manage accounts, dispatchers act for wardens"
        unknown = api.call("oper1", "POST", "/hazards/default/1/land", json={"warden": "warden1"})
        assert unknown.status_code == 422
