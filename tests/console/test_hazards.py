"""The hazards page in a real browser, on the real broker, worker and store: every hazard with its
history, live; steps taken for a warden, which its inbox is told of; wardens out of service and
back; who may press which button."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import httpx

from fleetbus.broker.accounts import Role
from fleetbus.publishers.client import RobotClient
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.hazards import Hazard, HazardState
from tests.console.support import Browser, Console, http_session, running_console
from tests.factories import hazard
from tests.support import Bus, notifications_until, read_inbox, wait_for

XSS = "<script>alert(1)</script>"
CARD = "#hazard-default-1"


def stored(bus: Bus) -> Hazard | None:
    """Hazard 1 of the default mission, as the store has it."""
    return bus.with_store(lambda store: store.hazards.get_hazard("default", 1))


def in_state(bus: Bus, state: HazardState) -> bool:
    found = stored(bus)
    return found is not None and found.state is state


def badge(browser: Browser, card: str = CARD) -> str:
    return browser.text(f"{card} .badge")


def open_live(console: Console, browser: Browser, user: str, role: UserRole) -> None:
    """A new user with ``role`` on the hazards page, live, marked so that a reload would show."""
    console.log_in(browser, console.user(user, role))
    browser.go(console.url("/console/hazards"))
    console.wait_live(browser)
    browser.driver.execute_script("document.body.dataset.marker = 'not reloaded'")


def not_reloaded(browser: Browser) -> bool:
    return browser.driver.execute_script("return document.body.dataset.marker") == "not reloaded"


def explorer_and_warden(bus: Bus) -> tuple[RobotClient, RobotClient]:
    """explorer1 and warden1, connected."""
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    return explorer, bus.robot(bus.add("warden1", Role.ROBOT, RobotKind.WARDEN))


def press(browser: Browser, button: str, notice: str) -> None:
    """Press ``button`` and wait for the notice that says it was done."""

    def pressed() -> bool:
        browser.click(button)  # replaced by a live update between finding and clicking: found again
        return True

    browser.until(pressed, f"{button} pressed")
    browser.until(lambda: notice in browser.text("#hazard-notice"), f"the notice {notice!r}")


def test_an_operator_claims_and_clears_a_hazard_for_a_warden_which_is_told_in_its_inbox(
    bus: Bus, browser: Browser
) -> None:
    explorer, warden = explorer_and_warden(bus)
    with bus.worker(), running_console(bus) as console:
        open_live(console, browser, "oper1", UserRole.OPERATOR)
        warden.publish("localisation", {"localised": True})
        sent = explorer.publish("hazard", hazard(0, description="Gas leak in bay 3"))
        browser.until(lambda: badge(browser) == "announced", "the hazard, announced, without a reload")
        assert "Gas leak in bay 3" in browser.text(CARD) and "explorer1" in browser.text(CARD)

        press(browser, f"{CARD} button[data-step=claim]", "claim for warden1; warden1 was told")
        assert badge(browser) == "claimed" and browser.text(f"{CARD} .claimer") == "warden1"
        press(browser, f"{CARD} button[data-step=reached]", "reached for warden1; warden1 was told")
        press(browser, f"{CARD} button[data-step=cleared]", "cleared for warden1; warden1 was told")
        assert badge(browser) == "cleared" and browser.find(f"{CARD} button") == []
        assert not_reloaded(browser)

        # the warden's own client hands out each step, after the announcement (its inbox, FIFO)
        notes = notifications_until(warden, lambda note: note.hazard_state == "cleared")
        assert [(n.hazard_id, n.hazard_state, n.claimed_by) for n in notes] == [
            (1, "announced", None),
            (1, "claimed", "warden1"),
            (1, "reached", "warden1"),
            (1, "cleared", "warden1"),
        ]
        assert all(note.event == sent for note in notes)
    cleared = stored(bus)
    assert cleared is not None and (cleared.state, cleared.claimed_by) == (HazardState.CLEARED, "warden1")
    assert cleared.claimed_at and cleared.reached_at and cleared.cleared_at


def test_a_warden_taken_out_of_service_on_the_page_leaves_the_gate_and_catches_up_when_back(
    bus: Bus, browser: Browser
) -> None:
    explorer = bus.robot(bus.add("explorer1", Role.ROBOT, RobotKind.EXPLORER))
    wardens = [bus.robot(bus.add(name, Role.ROBOT, RobotKind.WARDEN)) for name in ("warden1", "warden2")]
    with bus.worker(), running_console(bus) as console:
        open_live(console, browser, "super1", UserRole.SUPERVISOR)
        wardens[0].publish("localisation", {"localised": True})  # warden2 never localises

        press(browser, "#warden-warden2 button[data-change=out]", "warden2 out of service (by super1)")
        assert browser.text("#warden-warden2 .service").startswith("no (super1,")
        member = console.run(lambda: console.service.team.member("warden2"))
        assert (member.robot.in_service, member.robot.service_changed_by) == (False, "super1")
        browser.until(lambda: "open" in browser.text("#hazard-team h2"), "the gate open without warden2")

        sent = explorer.publish("hazard", hazard(0))
        browser.until(lambda: badge(browser) == "announced", "the hazard announced to warden1 alone")
        assert bus.ready_messages("warden2.inbox") == 0, "out of service: sent nothing"

        press(browser, "#warden-warden2 button[data-change=in]", "warden2 back in service (by super1)")
        caught_up = read_inbox(bus.admin_url, "warden2", lambda got: got[-1].hazard_id == 1, timeout=30)
        assert [(n.event, n.hazard_state) for n in caught_up] == [(sent, "announced")]
        assert browser.text("#warden-warden2 .service").startswith("yes (super1,")
        browser.until(
            lambda: "holds hazards" in browser.text("#hazard-team h2"), "warden2 holds the gate again"
        )
        assert not_reloaded(browser)


def test_new_hazards_and_their_steps_appear_live_and_what_a_robot_wrote_shows_as_text(
    bus: Bus, browser: Browser
) -> None:
    explorer, warden = explorer_and_warden(bus)
    with bus.worker(), running_console(bus) as console:
        open_live(console, browser, "admin1", UserRole.ADMIN)
        assert browser.text("#hazard-empty") == "No hazard has been reported."
        explorer.publish("hazard", hazard(0, description=XSS))
        browser.until(lambda: badge(browser) == "held", "the hazard, held, without a reload")
        assert browser.text(f"{CARD} .description") == XSS
        assert "waiting for warden1: not localised" in browser.text(f"{CARD} .why")
        assert not browser.find("#hazard-empty")[0].is_displayed()

        warden.publish("localisation", {"localised": True})
        browser.until(lambda: badge(browser) == "announced", "announced once warden1 localised")
        warden.claim_hazard(1)  # the warden's own request
        browser.until(lambda: browser.text(f"{CARD} .claimer") == "warden1", "its claim, live")
        explorer.publish("hazard", hazard(1, description="Second"))
        browser.until(lambda: len(browser.find("#hazard-list article")) == 2, "the second hazard, live")
        assert browser.texts("#hazard-list article .description") == ["Second", XSS], "newest first"
        assert not_reloaded(browser)

        browser.go(console.url("/console/hazards"))
        assert browser.texts("#hazard-list article .description") == ["Second", XSS]
        assert browser.find("#hazard-list script") == []
        assert not any("alert(1)" in line for line in browser.console_errors())


def test_only_supervisors_and_operators_see_the_buttons_and_others_get_403(bus: Bus) -> None:
    explorer, warden = explorer_and_warden(bus)
    with bus.worker(), running_console(bus) as console:
        for name, role in (
            ("admin1", UserRole.ADMIN),
            ("oper1", UserRole.OPERATOR),
            ("plan1", UserRole.PLANNER),
        ):
            console.user(name, role)
        warden.publish("localisation", {"localised": True})
        explorer.publish("hazard", hazard(0))
        wait_for(lambda: in_state(bus, HazardState.ANNOUNCED), what="the hazard announced")
        claim = "/console/hazards/steps/default/1/claim"
        with http_session(console, "admin1") as admin, http_session(console, "oper1") as operator:
            watched = admin.get("/console/hazards")
            assert watched.status_code == 200 and 'id="hazard-default-1"' in watched.text
            assert "hx-post" not in watched.text, "an admin watches: no button"
            assert 'data-step="claim"' in operator.get("/console/hazards").text
            refused = admin.post(claim, data={"warden": "warden1"})
            assert (
                refused.status_code == 403 and "may not use the buttons that act for wardens" in refused.text
            )
            assert admin.post("/console/hazards/wardens/warden1/out").status_code == 403
            assert in_state(bus, HazardState.ANNOUNCED), "nothing changed"
            assert console.run(lambda: console.service.team.member("warden1")).robot.in_service

            no_csrf = httpx.post(
                console.base + claim, data={"warden": "warden1"}, cookies=operator.cookies, timeout=30
            )
            assert no_csrf.status_code == 403 and "CSRF" in no_csrf.text
            not_a_warden = operator.post(claim, data={"warden": "explorer1"})
            assert "explorer1 is not a warden of the team" in not_a_warden.text
            taken = operator.post(claim, data={"warden": "warden1"})
            assert taken.status_code == 200 and "claim for warden1; warden1 was told" in taken.text
            too_soon = operator.post(claim.replace("claim", "cleared"), data={"warden": "warden1"})
            assert 'class="notice problem"' in too_soon.text
            assert "hazard 1 is claimed; warden1 cannot have it cleared" in too_soon.text
        with http_session(console, "plan1") as planner:
            assert planner.get("/console/hazards").status_code == 403
            assert planner.get("/console/stream/hazards").status_code == 403


def test_every_hazard_cleared_ones_too_newest_first_a_page_at_a_time(bus: Bus) -> None:
    settings = bus.settings.updated(console_hazards_page=2)
    with running_console(bus, settings) as console:
        console.user("oper1", UserRole.OPERATOR)

        async def three_hazards() -> None:
            store = console.service.repositories.hazards
            for seq in range(3):
                at = stored_at + timedelta(seconds=seq)
                event = {"body": hazard(seq, description=f"hazard {seq + 1}")}
                await store.add_hazard("default", "explorer1", "e", seq, event, at, held=False)
            await store.claim("default", 1, "warden1", stored_at)
            await store.mark_reached("default", 1, "warden1", stored_at)
            await store.mark_cleared("default", 1, "warden1", stored_at)

        stored_at = datetime.now(timezone.utc)
        console.run(three_hazards)
        with http_session(console, "oper1") as http:
            first = http.get("/console/hazards")
            assert first.text.index("hazard 3") < first.text.index("hazard 2")
            assert "hazard 1<" not in first.text and 'rel="next"' in first.text
            assert "data-stream=" in first.text
            second = http.get("/console/hazards?page=2")
            assert "hazard 1<" in second.text and "cleared" in second.text and 'rel="next"' not in second.text
            assert "data-stream=" not in second.text, "older pages are not live"
