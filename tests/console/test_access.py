"""Who may open what, for every page of the sitemap (pages added later included) and every role,
over real HTTP: 200 where the page admits the role, 403 elsewhere, and the navigation links
exactly the admitted pages; the administrators' actions refused to every other role."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager

import httpx
import pika
import pytest

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_FIELD, SESSION_COOKIE
from fleetbus.api.console.sitemap import ACCOUNT, PAGES
from fleetbus.broker.dead_letter_queue import peek_dead_letters
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import DEAD_LETTER_EXCHANGE, DEAD_LETTER_QUEUE, RobotKind
from tests.console.support import PASSWORD, Console, navigation, running_console
from tests.support import Bus


@pytest.fixture
def console(bus: Bus) -> Iterator[Console]:
    with running_console(bus) as running:
        for role in UserRole:
            running.user(_name(role), role)
        yield running


def _name(role: UserRole) -> str:
    return f"as-{role.value}"


@contextmanager
def _session(console: Console, role: UserRole) -> Iterator[httpx.Client]:
    """A client with a session of ``role`` (minted, as the login would) and the browser's CSRF cookie."""
    with httpx.Client(base_url=console.base, timeout=30) as http:
        assert http.get("/console/login").status_code == 200
        http.cookies.set(SESSION_COOKIE, console.session(_name(role)))
        yield http


def _linked(page: str) -> list[str]:
    return re.findall(r'href="([^"]*)"', navigation(page))


def test_each_page_answers_each_role_as_the_sitemap_says_and_links_exactly_its_pages(
    console: Console,
) -> None:
    wrong = []
    for role in UserRole:
        admitted = [page.path for page in PAGES if role in page.roles]
        with _session(console, role) as http:
            for page in (*PAGES, ACCOUNT):  # the own account page is linked from the name, not the nav
                answer = http.get(page.path)
                expected = 200 if role in page.roles else 403
                if answer.status_code != expected:
                    wrong.append(f"{page.path} as {role.value}: {answer.status_code}, not {expected}")
                if _linked(answer.text) != admitted:
                    wrong.append(f"{page.path} as {role.value} links {_linked(answer.text)}, not {admitted}")
                if expected == 403 and "may not use" not in answer.text:
                    wrong.append(f"{page.path} as {role.value}: the refusal does not say why")
    assert wrong == []


def _dead_letter(bus: Bus) -> str:
    """A letter in the dead-letter queue (put there by the administrator); its id."""
    with bus.admin_channel() as channel:
        channel.confirm_delivery()
        channel.basic_publish(DEAD_LETTER_EXCHANGE, "", b"refused", pika.BasicProperties(delivery_mode=2))
    [letter] = peek_dead_letters(bus.admin_url)
    return letter.letter_id


def test_the_administrators_actions_are_refused_to_every_other_role(console: Console) -> None:
    console.user("target1", UserRole.ROBOT, RobotKind.EXPLORER)
    letter = _dead_letter(console.bus)
    users = console.service.repositories.users
    before = console.run(lambda: users.get_user("target1"))
    console.session("target1")
    sessions = console.service.sessions
    actions = {
        "create a user": ("/console/accounts", {"name": "made1", "role": "admin", "password": PASSWORD}),
        "change a role": ("/console/accounts/target1/role", {"role": "inactive"}),
        "disable a user": ("/console/accounts/target1/disable", {}),
        "reset a broker password": ("/console/accounts/target1/broker-password", {}),
        "end a user's sessions": ("/console/accounts/target1/sessions/end", {}),
        "set a user's use cases": ("/console/accounts/target1/use-cases", {"scope": "only"}),
        "requeue a dead letter": (f"/console/dead-letters/{letter}/requeue", {}),
        "discard a dead letter": (f"/console/dead-letters/{letter}/discard", {}),
    }
    for role in set(UserRole) - {UserRole.ADMIN}:
        with _session(console, role) as http:
            csrf = {CSRF_FIELD: http.cookies[CSRF_COOKIE]}
            for what, (path, form) in actions.items():
                answer = http.post(path, data={**form, **csrf})
                assert answer.status_code == 403, f"{what} as {role.value}: {answer.status_code}"
                assert "may not use" in answer.text, answer.text
            shown = http.get("/console/accounts/target1/broker-password")
            assert shown.status_code == 403
    assert console.run(lambda: users.get_user("made1")) is None
    assert console.run(lambda: users.get_user("target1")) == before, "role and broker password unchanged"
    assert len(console.run(lambda: sessions.of("target1"))) == 1, "its session goes on"
    assert console.bus.ready_messages(DEAD_LETTER_QUEUE) == 1

    # the same requests from an administrator do what they say (so the 403s above were the role's)
    with _session(console, UserRole.ADMIN) as http:
        csrf = {CSRF_FIELD: http.cookies[CSRF_COOKIE]}
        answers = {what: http.post(path, data={**form, **csrf}) for what, (path, form) in actions.items()}
    assert {what: answer.status_code for what, answer in answers.items()} == {
        "create a user": 303,
        "change a role": 303,
        "disable a user": 303,
        "reset a broker password": 303,
        "end a user's sessions": 303,
        "set a user's use cases": 303,
        "requeue a dead letter": 502,  # this letter names no sender to publish it as
        "discard a dead letter": 303,
    }
    assert "no sender" in answers["requeue a dead letter"].text
    made = console.run(lambda: users.get_user("made1"))
    assert made is not None and made.role is UserRole.ADMIN
    after = console.run(lambda: users.get_user("target1"))
    assert after is not None and before is not None
    assert after.role is UserRole.INACTIVE and after.broker_secret != before.broker_secret
    assert (before.use_cases, after.use_cases) == (None, ())
    assert console.run(lambda: sessions.of("target1")) == []
    assert console.bus.ready_messages(DEAD_LETTER_QUEUE) == 0


def test_a_number_beyond_the_stores_integers_in_an_address_is_a_422_not_a_500(console: Console) -> None:
    """As the HTTP API bounds its ids: an alert, a map version or a page beyond 2**63 - 1 (SQLite's
    largest integer) is refused naming the parameter, not a store error."""
    huge = 2**64
    with _session(console, UserRole.ADMIN) as http:
        csrf = {CSRF_FIELD: http.cookies[CSRF_COOKIE]}
        answers = {
            "alert": http.post(f"/console/alerts/{huge}/acknowledge", data=csrf),
            "map": http.get(f"/console/map/{huge}.png"),
            "map query": http.get(f"/console/map?version={huge}"),
            "hazards page": http.get(f"/console/hazards?page={huge}"),
        }
    with _session(console, UserRole.PLANNER) as http:
        answers["plan map"] = http.get(f"/console/missions/new/map/{huge}.png")
    assert {what: answer.status_code for what, answer in answers.items()} == dict.fromkeys(answers, 422)
