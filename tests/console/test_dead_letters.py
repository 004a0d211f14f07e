"""The dead letters page in a real browser, on the real broker, worker and store: a poison message
with its reason and its message as text, what the full queue dropped, and an administrator's
requeue and discard counted over AMQP."""

from __future__ import annotations

import json
import uuid
from collections.abc import Sequence

import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.remote.webelement import WebElement

from fleetbus.broker.accounts import Account, Role
from fleetbus.schemas.notifications import Notification, Topic
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE, INGEST_QUEUE, EventType, RobotKind
from fleetbus.workers.overflow import dropped_from_queue
from fleetbus.workers.telemetry import BatteryWatch
from fleetbus.workers.validation import Accepted
from tests.console.support import Browser, Console, running_console
from tests.factories import status
from tests.support import Bus, read_inbox, wait_for

XSS = "<script>alert(1)</script>"


def _robot(console: Console, name: str) -> Account:
    """A robot made through the service (as an admin would), with the broker URL its login hands over."""
    console.user(name, UserRole.ROBOT, RobotKind.EXPLORER)
    user = console.run(lambda: console.service.repositories.users.get_user(name))
    assert user is not None
    return Account(name, Role.ROBOT, console.service.accounts.broker_credentials(user).amqp_url)


def _poison(bus: Bus, robot: Account, seq: int) -> str:
    """A status with a field no schema has (see tests/test_dead_letters.py), published raw; its message id."""
    message_id = uuid.uuid4().hex
    body = {"robot_id": robot.name, "seq": seq, "type": "status", "nope": XSS}
    bus.publish_raw(robot, f"{robot.name}.status", json.dumps(body).encode(), message_id=message_id)
    return message_id


def _letters(browser: Browser) -> list[WebElement]:
    return browser.find("article.letter")


def _letter(browser: Browser, reason: str) -> WebElement:
    [found] = [a for a in _letters(browser) if a.find_element(By.CSS_SELECTOR, ".reason").text == reason]
    return found


def test_a_poison_message_shows_with_its_reason_its_message_as_text_and_the_drops_counted(
    bus: Bus, browser: Browser
) -> None:
    bus.settings = bus.settings.updated(dead_letters_max=("1",))
    bus.service_accounts()  # `fleetbus setup`: the dead-letter queue's bound
    wait_for(
        lambda: bus.api.get_queue(bus.vhost, DEAD_LETTER_QUEUE).get("policy") == "fleetbus-dead-letters",
        what="the dead-letter queue bounded",
    )
    with running_console(bus) as console:
        console.user("oper1", UserRole.OPERATOR)
        explorer = _robot(console, "explorer1")
        with bus.worker() as worker:
            _poison(bus, explorer, 0)
            kept = _poison(bus, explorer, 1)
            wait_for(lambda: worker.stats().rejected == 2, what="both refused")
            counts = console.service.repositories.housekeeping.bound_counts
            wait_for(
                lambda: dropped_from_queue(console.run(counts), DEAD_LETTER_QUEUE) == 1,
                what="the full queue's drop counted",
            )
        console.log_in(browser, "oper1")
        browser.go(console.url("/console/dead-letters"))

        [letter] = _letters(browser)
        assert letter.find_element(By.CSS_SELECTOR, ".reason").text == "schema"
        assert "nope" in letter.find_element(By.CSS_SELECTOR, ".detail").text
        assert "from explorer1" in letter.text and "explorer1.status" in letter.text and kept in letter.text
        letter.find_element(By.CSS_SELECTOR, "summary").click()
        body = letter.find_element(By.CSS_SELECTOR, "pre.body").text
        assert json.loads(body)["nope"] == XSS, "the body as sent, as text"
        assert "x-death" in letter.find_element(By.CSS_SELECTOR, "pre.headers").text
        assert letter.find_elements(By.CSS_SELECTOR, "script") == []
        assert (browser.text("#in-queue"), browser.text("#dropped")) == ("1", "1")
        assert browser.find("form.requeue, form.discard") == [], "an operator reads; only admins change"
        assert [entry for entry in browser.console_errors() if "alert(1)" in entry] == []
    assert bus.ready_messages(DEAD_LETTER_QUEUE) == 1, "reading the page removed nothing"


def _buggy(monkeypatch: pytest.MonkeyPatch) -> None:
    """A bug in the battery watch that meets the status with 13 % (see tests/test_dead_letters.py)."""
    handle = BatteryWatch.handle

    async def buggy(self: BatteryWatch, accepted: Sequence[Accepted]) -> int:
        if any(item.record.body.get("battery_percent") == 13.0 for item in accepted):
            raise KeyError("a bug in the battery watch")
        return await handle(self, accepted)

    monkeypatch.setattr(BatteryWatch, "handle", buggy)


def _battery_warnings(note: Notification) -> bool:
    return note.topic is Topic.BATTERY


def test_an_admin_requeues_a_letter_once_the_bug_is_fixed_and_discards_a_poison_one(
    bus: Bus, browser: Browser, monkeypatch: pytest.MonkeyPatch
) -> None:
    with running_console(bus) as console:
        console.user("admin1", UserRole.ADMIN)
        console.user("oper1", UserRole.OPERATOR)  # its inbox gets the battery warnings
        account = _robot(console, "explorer1")
        robot = bus.robot(account)
        _buggy(monkeypatch)
        with bus.worker() as worker:
            robot.publish_many([(EventType.STATUS, status(b)) for b in (50.0, 13.0)])
            poison = _poison(bus, account, 1000)
            wait_for(lambda: len(bus.dead_letters()) == 2, what="the bug's letter and the poison one")
            assert worker.stats().internal_errors == 1
        monkeypatch.undo()  # the bug fixed: the battery warning of the 13 % status is still owed

        console.log_in(browser, "admin1")
        browser.go(console.url("/console/dead-letters"))
        _letter(browser, "internal-error").find_element(By.CSS_SELECTOR, "form.requeue button").click()
        browser.until(lambda: "published again" in browser.text(".notice"), "the requeue done")
        assert [a.find_element(By.CSS_SELECTOR, ".reason").text for a in _letters(browser)] == ["schema"]
        assert bus.ready_messages(DEAD_LETTER_QUEUE) == 1
        assert bus.ready_messages(INGEST_QUEUE) == 1, "published again, once, to where the robot sent it"
        with bus.worker() as worker:  # it passes the worker's checks as explorer1's (validated user id)
            notes = read_inbox(bus.admin_url, "oper1", lambda got: any(map(_battery_warnings, got)), 30)
            warnings = [note for note in notes if _battery_warnings(note)]
            assert [(n.event.robot_id, n.event.body.battery_percent) for n in warnings] == [
                ("explorer1", 13.0)
            ]
            # a sentinel behind it on its lane: once stored, the requeued one's batch was done
            robot.publish(EventType.STATUS, status(60.0))
            wait_for(lambda: bus.count(EventType.STATUS.value) == 3, what="the sentinel stored")
            assert worker.stats().internal_errors == 0
        assert bus.ready_messages(DEAD_LETTER_QUEUE) == 1, "not refused again"

        _letter(browser, "schema").find_element(By.CSS_SELECTOR, "form.discard button").click()
        browser.until(lambda: "discarded" in browser.text(".notice"), "the discard done")
        assert _letters(browser) == [] and browser.find("#no-letters")
        assert bus.ready_messages(DEAD_LETTER_QUEUE) == 0
        assert poison not in {e.message_id for e in bus.find()}, "discarded, never stored"
