"""Logging in against the real app, store and broker: tokens that expire, hashed passwords, the
broker account the login hands over, and each refusal answered 401/403 with a plain message and logged."""

from __future__ import annotations

import base64
import json
import logging
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone

import pika
import pika.exceptions
import pytest

from fleetbus.broker.accounts import can_login
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.roles import UserRole
from fleetbus.schemas.routing import ALL_TOPICS_BINDING, NOTIFY_EXCHANGE, inbox_queue
from tests.api.support import PASSWORD, PROBLEM_JSON, Api, problem, refusal, running_api
from tests.support import Bus, wait_for

SECURITY_LOG = "fleetbus.api.security"


@pytest.fixture
def api(bus: Bus) -> Iterator[Api]:
    with running_api(bus) as running:
        running.user("admin1", UserRole.ADMIN)
        yield running


def refusals(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == SECURITY_LOG]


def test_login_returns_an_expiring_token_and_working_broker_credentials(api: Api) -> None:
    api.user("alice", UserRole.OPERATOR)
    before = datetime.now(timezone.utc)
    reply = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
    assert reply.status_code == 200, reply.text
    body = reply.json()
    expires = datetime.fromisoformat(body["expires_at"].replace("Z", "+00:00"))  # 3.10 reads no Z
    assert timedelta(minutes=59) < expires - before <= timedelta(minutes=61)
    assert body["user"]["role"] == "operator" and body["token_type"] == "bearer"
    broker = body["broker"]
    assert broker["username"] == "alice" and broker["vhost"] == api.bus.vhost
    assert can_login(broker["amqp_url"]), "the broker account accepts the password the login handed over"
    connection = blocking_connection(broker["amqp_url"])
    channel = connection.channel()
    assert channel.queue_declare("alice.stream", passive=True).method.queue == "alice.stream"
    connection.close()
    me = api.client.get("/users/me", headers={"Authorization": f"Bearer {body['access_token']}"})
    assert me.status_code == 200 and me.json()["name"] == "alice"


def test_passwords_are_stored_as_argon2_hashes_and_broker_passwords_encrypted(api: Api) -> None:
    api.user("alice", UserRole.CLIENT)
    broker_password = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD}).json()[
        "broker"
    ]["password"]
    stored = api.run(lambda: api.service.repositories.users.get_user("alice"))
    assert stored is not None and stored.password_hash is not None and stored.broker_secret is not None
    assert stored.password_hash.startswith("$argon2id$") and PASSWORD not in stored.password_hash
    assert broker_password not in stored.broker_secret
    other = api.run(lambda: api.service.secrets.passwords.hash(PASSWORD))
    assert other != stored.password_hash, "salted: the same password hashes differently"


@pytest.mark.parametrize(
    ("username", "password"),
    [("alice", "wrong password!"), ("nobody", PASSWORD)],
    ids=["wrong password", "unknown user"],
)
def test_wrong_credentials_get_401_and_are_logged(
    api: Api, caplog: pytest.LogCaptureFixture, username: str, password: str
) -> None:
    api.user("alice", UserRole.CLIENT)
    with caplog.at_level(logging.WARNING, SECURITY_LOG):
        reply = api.client.post("/auth/token", data={"username": username, "password": password})
    assert refusal(reply) == (401, PROBLEM_JSON, problem(401, "wrong user name or password", "/auth/token"))
    assert reply.headers["WWW-Authenticate"] == "Bearer"
    assert [m for m in refusals(caplog) if f"POST /auth/token from 127.0.0.1 as {username}" in m]


@pytest.mark.parametrize(
    ("token", "detail"),
    [
        ("expired", "the token has expired; log in again"),
        ("tampered", "the token's signature is not valid (tampered with, or not ours)"),
        ("garbage", "the token is not valid: Not enough segments"),
        (None, "not logged in: send 'Authorization: Bearer <token>' from POST /auth/token"),
    ],
)
def test_bad_tokens_get_401_with_a_plain_message_and_are_logged(
    api: Api, caplog: pytest.LogCaptureFixture, token: str | None, detail: str
) -> None:
    tokens = api.service.secrets.tokens
    values = {
        "expired": tokens.issue("admin1", now=datetime.now(timezone.utc) - timedelta(hours=2)).value,
        "tampered": _tamper(tokens.issue("admin1").value),
        "garbage": "not-a-token",
    }
    headers = {"Authorization": f"Bearer {values[token]}"} if token else {}
    with caplog.at_level(logging.WARNING, SECURITY_LOG):
        reply = api.client.get("/users", headers=headers)
    assert refusal(reply) == (401, PROBLEM_JSON, problem(401, detail, "/users"))
    assert reply.headers["WWW-Authenticate"] == "Bearer"
    assert [m for m in refusals(caplog) if "refused 401: GET /users" in m and detail in m]


def _tamper(token: str) -> str:
    """Change the payload (make the subject someone else) and keep the old signature."""
    header, payload, signature = token.split(".")
    claims = json.loads(base64.urlsafe_b64decode(payload + "=" * (-len(payload) % 4)))
    claims["sub"] = "root"
    forged = base64.urlsafe_b64encode(json.dumps(claims).encode()).rstrip(b"=").decode()
    return f"{header}.{forged}.{signature}"


def test_a_guest_calling_an_admin_endpoint_gets_403_and_is_logged(
    api: Api, caplog: pytest.LogCaptureFixture
) -> None:
    api.user("visitor", UserRole.GUEST)
    with caplog.at_level(logging.WARNING, SECURITY_LOG):
        reply = api.call("visitor", "POST", "/users", json={"name": "mallory", "role": "admin"})
    assert refusal(reply) == (
        403,
        PROBLEM_JSON,
        problem(403, "role guest may not do this; it needs admin", "/users"),
    )
    assert api.run(lambda: api.service.repositories.users.get_user("mallory")) is None
    assert api.bus.api.get_user("mallory") is None, "no broker account made either"
    assert refusals(caplog) == [
        "refused 403: POST /users from 127.0.0.1 as visitor (guest): "
        "role guest may not do this; it needs admin"
    ]


def test_a_new_account_is_inactive_may_not_log_in_and_has_no_broker_access(api: Api) -> None:
    created = api.call("admin1", "POST", "/users", json={"name": "newbie", "password": PASSWORD})
    assert created.status_code == 201 and created.json()["role"] == "inactive"
    reply = api.client.post("/auth/token", data={"username": "newbie", "password": PASSWORD})
    assert refusal(reply) == (
        403,
        PROBLEM_JSON,
        problem(403, "user newbie is inactive: an admin must give it a role first", "/auth/token"),
    )
    stored = api.run(lambda: api.service.repositories.users.get_user("newbie"))
    assert stored is not None
    url = api.service.accounts.broker_credentials(stored).amqp_url
    with pytest.raises(pika.exceptions.ProbableAccessDeniedError):
        blocking_connection(url)  # right password, no permission on the vhost
    # an admin activates it: the same broker password now opens its own queues
    assert api.call("admin1", "PUT", "/users/newbie/role", json={"role": "client"}).status_code == 200
    login = api.client.post("/auth/token", data={"username": "newbie", "password": PASSWORD})
    assert login.status_code == 200 and login.json()["broker"]["amqp_url"] == url
    connection = blocking_connection(url)
    connection.channel().queue_declare("newbie.inbox", passive=True)
    connection.close()


def test_a_role_change_takes_effect_on_the_next_request(api: Api) -> None:
    api.user("alice", UserRole.SUPERVISOR)
    assert api.call("alice", "GET", "/users").status_code == 200
    assert api.call("admin1", "PUT", "/users/alice/role", json={"role": "guest"}).status_code == 200
    reply = api.call("alice", "GET", "/users")  # the same token
    assert (reply.status_code, reply.json()["detail"]) == (
        403,
        "role guest may not do this; it needs admin or supervisor",
    )
    assert api.call("admin1", "DELETE", "/users/alice").status_code == 204
    gone = api.call("alice", "GET", "/users/me")
    ended = "the session has ended (logged out, ended by an admin, or a password change); log in again"
    assert (gone.status_code, gone.json()["detail"]) == (401, ended)  # a removal ends its sessions
    assert api.bus.api.get_user("alice") is None, "its broker account went with it"


def test_a_user_disabled_is_cut_off_the_broker_at_once(api: Api) -> None:
    """A disabled user's permissions go, and so do the connections it has open: a connection keeps
    what it was allowed when it opened (a consumer goes on receiving), so the broker closes them."""
    api.user("carol", UserRole.CLIENT)
    stored = api.run(lambda: api.service.repositories.users.get_user("carol"))
    assert stored is not None
    connection = blocking_connection(api.service.accounts.broker_credentials(stored).amqp_url)
    try:
        connection.channel().queue_declare("carol.inbox", passive=True)
        # a connection is listed by the broker a moment after it opens (as every long-lived one is)
        wait_for(lambda: "carol" in {c["user"] for c in api.bus.api.list_connections()}, what="listed")
        assert api.call("admin1", "PUT", "/users/carol/role", json={"role": "inactive"}).status_code == 200
        with pytest.raises(pika.exceptions.ConnectionClosedByBroker) as closed:
            connection.process_data_events(time_limit=30)
        assert "carol's role changed to inactive" in str(closed.value)
    finally:
        if connection.is_open:
            connection.close()


def test_an_operator_given_another_role_keeps_nothing_of_an_operators_on_the_broker(api: Api) -> None:
    """Its inbox no longer takes every notification, its stream (every beacon) and its commands
    exchange go; while it has robots mounted, the change is refused, as a removal is."""
    broker, vhost = api.bus.api, api.bus.vhost
    api.user("dave", UserRole.OPERATOR)

    def inbox_keys() -> list[str]:
        bound = broker.exchange_bindings(vhost, NOTIFY_EXCHANGE)
        return [b["routing_key"] for b in bound if b["destination"] == inbox_queue("dave")]

    assert inbox_keys() == [ALL_TOPICS_BINDING] and broker.get_exchange(vhost, "dave.commands") is not None
    assert api.call("admin1", "PUT", "/users/dave/role", json={"role": "guest"}).status_code == 200
    assert inbox_keys() == []
    assert broker.get_exchange(vhost, "dave.commands") is None
    assert "dave.stream" not in {q["name"] for q in broker.list_queues(vhost)}
    # an operator disabled likewise: nothing goes on filling its inbox and stream
    api.user("erin", UserRole.OPERATOR)
    assert api.call("admin1", "PUT", "/users/erin/role", json={"role": "inactive"}).status_code == 200
    bound = broker.exchange_bindings(vhost, NOTIFY_EXCHANGE)
    assert [b for b in bound if b["destination"] == inbox_queue("erin")] == []
    assert broker.get_exchange(vhost, "erin.commands") is None
    assert "erin.stream" not in {q["name"] for q in broker.list_queues(vhost)}


def test_users_cannot_be_created_twice_or_with_bad_names_or_short_passwords(api: Api) -> None:
    api.user("alice", UserRole.CLIENT)
    cases = [
        ({"name": "alice", "password": PASSWORD}, 409, "user 'alice' exists"),
        ({"name": "Bad.Name", "password": PASSWORD}, 422, "invalid name 'Bad.Name'"),
        ({"name": "bob", "password": "short"}, 422, "at least 10 characters"),
        (
            {"name": "bob", "password": PASSWORD, "role": "client", "kind": "warden"},
            422,
            "kind applies to robots only",
        ),
    ]
    for body, status, detail in cases:
        reply = api.call("admin1", "POST", "/users", json=body)
        assert reply.status_code == status and detail in reply.json()["detail"], (body, reply.text)
    assert [u.name for u in api.run(api.service.repositories.users.users)] == ["admin1", "alice"]


def test_an_admin_cannot_take_its_own_admin_role_away(api: Api) -> None:
    for role in ("client", "inactive"):  # inactive: disabling itself
        reply = api.call("admin1", "PUT", "/users/admin1/role", json={"role": role})
        assert (reply.status_code, reply.json()["detail"]) == (
            422,
            "an admin cannot take its own admin role away (ask another admin)",
        )
    stored = api.run(lambda: api.service.repositories.users.get_user("admin1"))
    assert stored is not None and stored.role is UserRole.ADMIN


def test_a_broker_password_reset_locks_the_old_one_out_and_the_login_hands_out_the_new(
    api: Api, caplog: pytest.LogCaptureFixture
) -> None:
    api.user("alice", UserRole.OPERATOR)
    old = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD}).json()["broker"]
    with caplog.at_level(logging.DEBUG):
        new = api.run(lambda: api.service.accounts.reset_broker_password("alice", by="admin1"))
    assert new.password != old["password"] and new.username == "alice"
    assert not [r for r in caplog.records if new.password in r.getMessage()], "never in a log"
    assert "broker password reset by admin1" in caplog.text
    with pytest.raises(pika.exceptions.ProbableAuthenticationError):
        blocking_connection(old["amqp_url"])
    connection = blocking_connection(new.amqp_url)
    connection.channel().queue_declare("alice.stream", passive=True)  # its permissions kept
    connection.close()
    login = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
    assert login.json()["broker"]["amqp_url"] == new.amqp_url
