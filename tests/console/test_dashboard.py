"""The dashboard in a real browser, on the real broker, worker and store."""

from __future__ import annotations

import json
import re
import time
import uuid

import pytest

from fleetbus.broker.accounts import Role
from fleetbus.broker.management import ManagementAPI
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from tests.api.server import free_port
from tests.console.support import Browser, report_live, running_console
from tests.factories import hazard, status
from tests.run_tls import BROKER_TLS
from tests.support import Bus

XSS = "<script>alert(1)</script>"


def shown_live_within(browser: Browser, condition: object, what: str, since: float) -> float:
    """Wait for ``condition`` (generously, to fail with a message), then say how long it took."""
    browser.until(condition, what)  # type: ignore[arg-type]
    return time.monotonic() - since


def test_a_published_hazard_appears_on_the_dashboard_live_without_a_reload(
    bus: Bus, browser: Browser
) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        assert browser.driver.current_url == console.url("/console/")
        console.wait_live(browser)
        browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")
        # a first event through the whole chain: the worker is up and consuming
        explorer.publish("status", status(80.0))
        browser.until(lambda: "80 %" in browser.text("#robot-explorer1 td.battery"), "the first status")

        published = time.monotonic()
        explorer.publish("hazard", hazard(0, description="Smoke in corridor B"))
        row = shown_live_within(
            browser,
            lambda: any("Smoke in corridor B" in row for row in browser.texts("#events tr")),
            "the hazard's row on the dashboard",
            published,
        )
        counted = shown_live_within(
            browser,
            lambda: browser.text("#hazards-held") + browser.text("#hazards-announced") != "00",
            "the hazard counted by state",
            published,
        )
        # the list of the newest hazards is a fragment of its own: it may arrive after the counts
        listed = shown_live_within(
            browser,
            lambda: bool(browser.find("#dashboard-hazard-default-1")),
            "the hazard listed by its id",
            published,
        )
        report_live("the hazard on the dashboard", max(row, counted, listed))
        assert "explorer1" in browser.text("#events tr")
        assert "explorer" in browser.text("#robot-explorer1")
        assert browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"


def test_battery_and_connection_of_a_robot_that_sent_a_status(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    bus.add("warden1", Role.ROBOT, RobotKind.WARDEN)  # never connects, never reports
    with bus.worker(), running_console(bus, bus.settings.updated(console_broker_poll_s=0.5)) as console:
        explorer.publish("status", status(42.0))  # before the page opens: read from the store once
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        browser.until(lambda: "42 %" in browser.text("#robot-explorer1 td.battery"), "the stored battery")
        console.wait_live(browser)
        explorer.publish("status", status(17.0))  # after: from the live feed
        browser.until(lambda: "17 %" in browser.text("#robot-explorer1 td.battery"), "the new battery")
        assert browser.find("#robot-explorer1 td.battery .bad"), "below FLEETBUS_BATTERY_LOW_PERCENT"
        browser.until(
            lambda: browser.text("#robot-explorer1 td.connected") == "yes", "explorer1 connected", timeout=30
        )
        assert browser.text("#robot-warden1 td.connected") == "no"
        assert browser.text("#robot-warden1 td.battery") == "no status"
        assert "stale" in browser.text("#robot-warden1")


@pytest.mark.rabbitmq_versions  # what the management API answers differs between releases
def test_broker_health_lists_the_fleetbus_queues_with_their_consumers(bus: Bus, browser: Browser) -> None:
    with bus.worker(), running_console(bus, bus.settings.updated(console_broker_poll_s=0.5)) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        console.wait_live(browser)

        def consumers(queue: str) -> int:
            for row in browser.find("#broker-queues tbody tr"):
                cells = [cell.text for cell in row.find_elements("css selector", "td")]
                if cells and cells[0] == queue:
                    return int(cells[4])
            return 0

        # the management API counts consumers from statistics it gathers every few seconds
        browser.until(
            lambda: consumers("fleetbus.ingest.events") >= 1 and consumers("fleetbus.rpc.requests") >= 1,
            "the worker consuming its queues",
            timeout=30,
        )
        rows = {row.split()[0]: row.split() for row in browser.texts("#broker-queues tbody tr")}
        assert {"fleetbus.ingest.events", "fleetbus.dead-letters", "fleetbus.rpc.requests"} <= set(rows)
        assert all(name.startswith("fleetbus.") for name in rows), rows
        assert rows["fleetbus.ingest.events"][1] == "quorum"
        assert rows["fleetbus.dead-letters"][1] == "classic"
        # the node's figures, as the release the suite runs on reports them
        node = browser.text("#broker-health table.nodes tbody tr")
        memory = re.search(r"yes (\d+) of (\d+) MiB ([\d.]+) GiB (\d+) of (\d+)", node)
        assert memory, node
        used, limit, _, descriptors, most = (float(figure) for figure in memory.groups())
        assert 0 < used < limit and 0 < descriptors < most, node
        tls_line = browser.text("#broker-tls")
        if BROKER_TLS:  # the certificate the node presents, read as a client meets it
            assert re.search(r"expires on \d{4}-\d{2}-\d{2}, in \d+ days", tls_line), tls_line
        else:
            assert "not used" in tls_line


def test_a_poison_message_counts_among_the_dead_letters_of_the_last_hour(bus: Bus, browser: Browser) -> None:
    account = bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER)
    with bus.worker(), running_console(bus, bus.settings.updated(console_broker_poll_s=0.5)) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        console.wait_live(browser)
        browser.until(lambda: browser.text("#dead-letters-hour") == "0", "no dead letter yet")
        poison = json.dumps({"robot_id": "explorer1", "seq": 0, "type": "status", "nope": 1}).encode()
        bus.publish_raw(account, "explorer1.status", poison, message_id=uuid.uuid4().hex)
        # read when the queue's depth changes, which the management API tells within seconds
        browser.until(
            lambda: browser.text("#dead-letters-hour") == "1", "the poison message counted", timeout=30
        )
        assert "schema 1" in browser.text("#dead-letters .reasons")
        assert browser.text("#dead-letters-queued") == "1"


def test_what_a_robot_sent_shows_as_text_never_as_markup(bus: Bus, browser: Browser) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    with bus.worker(), running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        console.log_in(browser, "oper1")
        console.wait_live(browser)
        explorer.publish("hazard", hazard(0, description=XSS))
        browser.until(lambda: XSS in browser.texts("#events td.summary"), "the hazard, live")
        browser.go(console.url("/console/"))
        browser.until(lambda: XSS in browser.texts("#events td.summary"), "the hazard, as first rendered")
        assert browser.find("#events script") == []
        assert not any("alert(1)" in line for line in browser.console_errors())


def test_planners_and_clients_see_their_own_work_and_not_the_live_team(bus: Bus) -> None:
    with running_console(bus) as console:
        for name, role in (("plan1", UserRole.PLANNER), ("client1", UserRole.CLIENT)):
            console.user(name, role)
            with console.http_as(name) as http:
                page = http.get("/console/")
                assert page.status_code == 200 and 'id="my-work"' in page.text
                assert 'id="team"' not in page.text, "no team"
                assert 'data-stream="/console/stream/my-work"' in page.text, "their own work, live"
                refused = http.get("/console/stream/dashboard")
                assert refused.status_code == 403
                assert "may not use the live team on the dashboard" in refused.text
        console.user("oper1", UserRole.OPERATOR)
        with console.http_as("oper1") as http:
            page = http.get("/console/")
            assert page.status_code == 200 and 'id="my-work"' in page.text and 'id="team"' in page.text


def test_a_management_api_that_does_not_answer_is_shown_as_such(bus: Bus, browser: Browser) -> None:
    bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER)
    with running_console(bus, bus.settings.updated(console_broker_poll_s=0.5)) as console:
        console.user("oper1", UserRole.OPERATOR)
        answering = console.service.management
        console.service.management = ManagementAPI(f"http://127.0.0.1:{free_port()}/", "admin", "secret")
        try:
            console.log_in(browser, "oper1")
            console.wait_live(browser)
            browser.until(
                lambda: "the management API did not answer" in browser.text("#broker-problem"),
                "the broker's health says why it is unknown",
            )
            assert browser.text("#robot-explorer1 td.connected") == "unknown"
            assert "secret" not in browser.text("#broker-health")
            assert browser.find("#live-status")[0].get_attribute("data-state") == "live", "the page goes on"
        finally:
            console.service.management.close()
            console.service.management = answering


def test_the_team_panel_lists_a_bounded_page_those_that_need_attention_first(bus: Bus) -> None:
    with running_console(bus, bus.settings.updated(console_team_rows=2)) as console:
        for name in ("rank-a", "rank-b", "rank-c"):
            console.user(name, UserRole.ROBOT, RobotKind.WARDEN)
        console.run(lambda: console.service.team.set_in_service("rank-c", False, "test"))
        console.user("oper2", UserRole.OPERATOR)
        with console.http_as("oper2") as http:
            page = http.get("/console/").text
        rows = re.findall(r'<tr id="robot-([a-z0-9-]+)"', page)
        assert rows == ["rank-c", "rank-a"], rows  # out of service first, then by name; rank-b counted
        assert "3 robots (the 2 that need attention first" in page
        assert 'href="/console/map#map-robots"' in page, "the heading points to where all are listed"
        with console.http_as("oper2") as http:
            listed = re.findall(r'<tr id="map-robot-([a-z0-9-]+)"', http.get("/console/map").text)
        assert sorted(listed) == ["rank-a", "rank-b", "rank-c"], "the live map lists every robot"
