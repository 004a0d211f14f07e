"""One account registry: the command line, the HTTP API and the console go through the same
accounts service, on the real broker and store, with the same checks and outcome; the registry
check finds what drifted from it and repairs it, the same from each."""

from __future__ import annotations

import asyncio
import json
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import unquote, urlsplit

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_HEADER, SESSION_COOKIE
from fleetbus.broker.accounts import Role, can_login, provision_account, url_for
from fleetbus.broker.shards import read_shard_map
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import SHARD_EXCHANGE, RobotKind, ingest_shard_queue, shard_binding_keys
from tests.api.support import PASSWORD, Api, running_api
from tests.commands import fleetbus
from tests.support import Bus


def _fresh(bus: Bus, *names: str) -> None:
    """Names the commands will make: broker users are broker-wide, so one an aborted run left is
    removed first, and each is removed after the test."""
    for name in names:
        bus.api.delete_user(name)
        bus.accounts.append(name)


def _console(api: Api, name: str) -> str:
    """Log ``name``'s browser in to the console (a minted session, as a login makes); its CSRF value."""
    api.client.get("/console/login")
    api.client.cookies.set(SESSION_COOKIE, api.session(name))
    return api.client.cookies[CSRF_COOKIE]


def test_users_add_and_add_many_record_the_user_as_post_users_does(bus: Bus, tmp_path: Path) -> None:
    _fresh(bus, "cli-robot", "many-a", "many-b")
    added = fleetbus(bus, "users", "add", "cli-robot", "--kind", "explorer")
    assert added.returncode == 0, added.stderr
    names = tmp_path / "robots.txt"
    names.write_text("many-a\nmany-b warden\n")
    many = fleetbus(bus, "users", "add-many", str(names), "--urls", str(tmp_path / "urls.txt"))
    assert many.returncode == 0, many.stderr
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        for name, kind in (("cli-robot", "explorer"), ("many-a", None), ("many-b", "warden")):
            found = api.call("admin1", "GET", f"/users/{name}")
            assert found.status_code == 200, found.text
            assert (found.json()["role"], found.json()["kind"]) == ("robot", kind)
        again = api.call("admin1", "POST", "/users", json={"name": "cli-robot", "role": "robot"})
        assert (again.status_code, again.json()["detail"]) == (409, "user 'cli-robot' exists")
        _console(api, "admin1")
        page = api.client.get("/console/accounts")
        assert page.status_code == 200 and all(n in page.text for n in ("cli-robot", "many-a", "many-b"))
        # the broker password the registry keeps is the one the command handed out
        url = next(line for line in added.stdout.split() if line.startswith("amqp"))
        user = api.run(lambda: api.service.repositories.users.get_user("cli-robot"))
        assert user is not None
        kept = api.service.accounts.broker_credentials(user).password
        assert kept == unquote(urlsplit(url).password or "")
        team = {robot.name: robot.kind for robot in api.run(api.service.repositories.hazards.robots)}
        assert team == {"cli-robot": "explorer", "many-a": None, "many-b": "warden"}


def test_reserved_names_are_refused_alike_by_the_command_line_and_the_api(bus: Bus) -> None:
    admin = unquote(urlsplit(bus.admin_url).username or "")
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        for name in ("fleetbus-x", admin):
            by_api = api.call("admin1", "POST", "/users", json={"name": name, "role": "robot"})
            by_cli = fleetbus(bus, "users", "add", name)
            assert by_api.status_code == 422
            assert by_cli.returncode == 2
            assert by_api.json()["detail"] in " ".join(by_cli.stderr.split())
    assert bus.api.get_user("fleetbus-x") is None


def test_the_command_line_refuses_to_remove_a_mounted_user_as_the_api_does(bus: Bus) -> None:
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("oper1", UserRole.OPERATOR)
        api.user("mounted1", UserRole.ROBOT, RobotKind.EXPLORER)
        now = datetime.now(timezone.utc)
        api.run(lambda: api.service.repositories.channels.mount("mounted1", "oper1", "m-1", now))
        by_api = api.call("admin1", "DELETE", "/users/mounted1")
        by_cli = fleetbus(bus, "users", "remove", "mounted1")
        assert by_api.status_code == 409 and by_cli.returncode == 1
        assert by_api.json()["detail"] in " ".join(by_cli.stderr.split())
        assert api.call("admin1", "GET", "/users/mounted1").status_code == 200
        assert bus.api.get_user("mounted1") is not None


def test_shards_list_the_registrys_robots_only(bus: Bus) -> None:
    _fresh(bus, "shard-a", "shard-b")
    for name in ("shard-a", "shard-b"):
        assert fleetbus(bus, "users", "add", name).returncode == 0
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("turned1", UserRole.ROBOT)  # a robot that becomes an operator
        assert api.call("admin1", "PUT", "/users/turned1/role", json={"role": "operator"}).status_code == 200
        removed = fleetbus(bus, "users", "remove", "shard-b")
        assert removed.returncode == 0, removed.stderr
        listed = fleetbus(bus, "shards", "--json")
        assert listed.returncode == 0, listed.stderr
        document = json.loads(listed.stdout)
        named = {robot for state in document["states"] for robot in state["robots"]}
        assert named == {"shard-a"} and document["unassigned"] == []


def test_the_registry_check_finds_drift_and_repairs_it_alike_everywhere(bus: Bus) -> None:
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("drift-r", UserRole.ROBOT, RobotKind.WARDEN)
        api.user("drift-o", UserRole.OPERATOR)
        # a broker account made beside the registry
        bus.accounts.append("outsider1")
        asyncio.run(provision_account(bus.admin_url, bus.api, "outsider1", Role.ROBOT, rotate=True))
        bus.api.delete_permissions(bus.vhost, "drift-o")
        [shard] = read_shard_map(bus.api, bus.vhost, 1).bindings["drift-r"]
        bus.api.unbind_keys(
            bus.vhost, SHARD_EXCHANGE, ingest_shard_queue(shard), shard_binding_keys("drift-r")
        )
        api.run(lambda: api.service.repositories.hazards.remove_robot("drift-r"))
        expected = [
            ("outside", "outsider1"),
            ("permissions", "drift-o"),
            ("shard", "drift-r"),
            ("team", "drift-r"),
        ]

        by_cli = fleetbus(bus, "users", "check", "--json")
        assert by_cli.returncode == 1, by_cli.stderr
        cli_drift = json.loads(by_cli.stdout)["drift"]
        assert [(d["kind"], d["name"]) for d in cli_drift] == expected
        by_api = api.call("admin1", "GET", "/registry/drift")
        assert by_api.status_code == 200 and by_api.json()["drift"] == cli_drift
        # `users list` lists the registry, each user's drift flagged, the rest after them
        listed = fleetbus(bus, "users", "list", "--json")
        assert listed.returncode == 0, listed.stderr
        users = json.loads(listed.stdout)["users"]
        assert {u["name"]: [(d["kind"], d["name"]) for d in u["drift"]] for u in users} == {
            "admin1": [],
            "drift-o": [("permissions", "drift-o")],
            "drift-r": [("shard", "drift-r"), ("team", "drift-r")],
        }
        assert [d for u in users for d in u["drift"]] == [d for d in cli_drift if d["name"] != "outsider1"]
        assert json.loads(listed.stdout)["other_drift"] == [d for d in cli_drift if d["name"] == "outsider1"]
        assert [(u["role"], u["kind"], u["login"]) for u in users] == [
            ("admin", None, "password"),
            ("operator", None, "password"),
            ("robot", "warden", "password"),
        ]
        table = fleetbus(bus, "users", "list").stdout
        assert "broker account outsider1 is not in the registry" in table
        assert all(f"│ {name} " in table for name in ("admin1", "drift-o", "drift-r"))
        csrf = _console(api, "admin1")
        page = api.client.get("/console/")
        assert all(d["problem"] in page.text.replace("&#39;", "'") for d in cli_drift)
        assert "registry-repair" in page.text
        assert api.client.post("/console/registry/repair").status_code == 403  # no CSRF value
        assert api.call("admin1", "GET", "/registry/drift").json()["drift"] == cli_drift

        repaired = api.client.post(
            "/console/registry/repair", headers={CSRF_HEADER: csrf}, follow_redirects=False
        )
        assert repaired.status_code == 303
        assert api.client.get(repaired.headers["location"]).text.count("registry-agrees") == 1
        assert fleetbus(bus, "users", "check").returncode == 0
        assert api.call("admin1", "GET", "/registry/drift").json()["drift"] == []
        after = json.loads(fleetbus(bus, "users", "list", "--json").stdout)
        assert [(u["name"], u["drift"]) for u in after["users"]] == [
            (name, []) for name in ("admin1", "drift-o", "drift-r", "outsider1")
        ]
        assert after["other_drift"] == []
        outsider = api.call("admin1", "GET", "/users/outsider1").json()
        assert (outsider["role"], bus.api.get_user("outsider1") is not None) == ("robot", True)
        assert read_shard_map(bus.api, bus.vhost, 1).bindings["drift-r"] == (0,)


def test_a_repair_from_the_command_line_is_a_repair_through_the_api(bus: Bus) -> None:
    with running_api(bus) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("gone-r", UserRole.ROBOT)
        bus.api.delete_user("gone-r")  # its broker account lost
        listed = api.call("admin1", "POST", "/registry/repair").json()
        assert [(d["kind"], d["name"]) for d in listed["repaired"]] == [("account", "gone-r")]
        assert listed["drift"] == []
        # the new broker password is the registry's: the login hands out one that works
        token = api.client.post("/auth/token", data={"username": "gone-r", "password": PASSWORD})
        assert token.status_code == 200
        assert can_login(url_for(bus.admin_url, "gone-r", token.json()["broker"]["password"]))


def test_the_tests_accounts_are_made_as_users_make_them(bus: Bus) -> None:
    """`Bus.add` goes through the accounts service: its users are the registry's, nothing drifts."""
    bus.add("reg-warden", kind=RobotKind.WARDEN)
    bus.add("reg-oper", Role.OPERATOR)
    listed = fleetbus(bus, "users", "list", "--json")
    assert listed.returncode == 0, listed.stderr
    users = [(u["name"], u["role"], u["kind"], u["drift"]) for u in json.loads(listed.stdout)["users"]]
    assert users == [("reg-oper", "operator", None, []), ("reg-warden", "robot", "warden", [])]
    assert fleetbus(bus, "users", "check").returncode == 0
