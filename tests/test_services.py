"""Request/reply services against the real broker: claims, lookups, and a service that is down."""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from datetime import datetime, timezone
from typing import Any

import pika
import pytest

import fleetbus.workers.runner
from fleetbus.publishers.rpc import RpcChannel, ServiceFailed, ServiceRefused, ServiceTimeout
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event
from fleetbus.schemas.routing import RobotKind, request_routing_key, requests_exchange
from fleetbus.schemas.services import REPLY_TO
from fleetbus.workers.store.hazards import Hazard, HazardState, SiteApplied
from fleetbus.workers.store.repositories import Repositories
from tests.factories import hazard
from tests.support import Bus, wait_for


def team(bus: Bus) -> tuple:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    wardens = [bus.robot(bus.add(name, kind=RobotKind.WARDEN)) for name in ("warden1", "warden2")]
    return explorer, wardens


def raw_calls(amqp_url: str, robot: str, method: str, requests: list[tuple[str | None, bytes]]) -> list[Any]:
    """The replies to ``requests`` (each a content_type and a body) to ``method``, published as a
    robot in another language might, in order, on one connection."""
    connection = blocking_connection(amqp_url)
    try:
        channel = connection.channel()
        replies: dict[str, Any] = {}
        channel.basic_consume(
            REPLY_TO,
            lambda _ch, _m, props, body: replies.__setitem__(props.correlation_id, json.loads(body)),
            auto_ack=True,
        )
        for n, (content_type, body) in enumerate(requests):
            properties = pika.BasicProperties(
                content_type=content_type, reply_to=REPLY_TO, correlation_id=str(n), user_id=robot
            )
            channel.basic_publish(
                requests_exchange(robot), request_routing_key(robot, method), body, properties
            )
        deadline = time.monotonic() + 30
        while len(replies) < len(requests) and time.monotonic() < deadline:
            connection.process_data_events(time_limit=0.2)
        return [replies.get(str(n)) for n in range(len(requests))]
    finally:
        connection.close()


def test_services(bus: Bus) -> None:
    explorer = bus.robot(bus.add("explorer1", kind=RobotKind.EXPLORER))
    account1, account2 = (bus.add(name, kind=RobotKind.WARDEN) for name in ("warden1", "warden2"))
    warden1, warden2 = bus.robot(account1), bus.robot(account2)
    with bus.worker() as worker:
        for warden in (warden1, warden2):
            warden.publish("localisation", {"localised": True})
        sent = explorer.publish_many([("hazard", hazard(0, "Fire")), ("hazard", hazard(1, "Gas leak"))])
        warden1.receive(2, timeout=30)

        assert [w["name"] for w in warden1.wardens() if w["localised"]] == ["warden1", "warden2"]
        claimed = warden1.claim_hazard(1)
        assert (claimed["state"], claimed["claimed_by"]) == ("claimed", "warden1")
        with pytest.raises(ServiceRefused, match="claimed by warden1"):
            warden2.claim_hazard(1)
        with pytest.raises(ServiceRefused, match="no hazard 99"):
            warden2.claim_hazard(99)
        with pytest.raises(ServiceRefused, match="hazard_id must be an integer from 1 to"):
            warden2.call("hazard.claim", hazard_id="one")
        with pytest.raises(ServiceRefused, match=r"no service 'hazard\.teleport'"):
            warden2.call("hazard.teleport")
        assert worker.context is not None
        assert worker.context.rpc.bad_requests == 1, "a service that does not exist: counted (fleetbus stats)"
        assert warden1.hazard(1)["claimed_by"] == "warden1", "a refused claim changes nothing"

        reached = warden1.hazard_reached(1)
        assert reached["state"] == "reached" and reached["reached_at"]
        warden2.claim_hazard(2)
        assert warden2.release_hazard(2)["state"] == "announced"
        hazard_1 = warden1.hazard(1)
        assert hazard_1["event"]["body"] == sent[0].body.model_dump(mode="json")
        # a hazard another warden holds is its own: each robot is given the unclaimed ones and its own
        assert [(h["hazard_id"], h["state"]) for h in warden1.open_hazards()] == [
            (1, "reached"),
            (2, "announced"),
        ]
        for robot in (warden2, explorer):
            assert [(h["hazard_id"], h["state"]) for h in robot.open_hazards()] == [(2, "announced")]

        # a request that is not JSON by its content type is refused, counted, and changes nothing
        claim = json.dumps({"hazard_id": 2}).encode()
        sent: list[tuple[str | None, bytes]] = [
            ("text/plain", claim),
            (None, claim),
            ("application/json; charset=latin-1", claim),
            (None, b"\xff"),
        ]
        replies = raw_calls(account2.amqp_url, "warden2", "hazard.claim", sent)
        wanted = "service requests are application/json"
        none = f"the message has no content_type property; {wanted}"
        assert replies == [
            {"ok": False, "error": f"content_type is 'text/plain'; {wanted} (UTF-8)"},
            {"ok": False, "error": none},
            {"ok": False, "error": f"content_type is 'application/json; charset=latin-1'; {wanted} (UTF-8)"},
            {"ok": False, "error": none},
        ]
        assert warden2.hazard(2)["state"] == "announced", "no request of them was processed"
        assert worker.context is not None
        assert worker.context.rpc.bad_requests == 1 + 4, "these, and the service that does not exist above"
        assert worker.context.rpc.internal_errors == 0


def test_two_wardens_claim_at_the_same_instant_one_gets_it(bus: Bus) -> None:
    explorer, wardens = team(bus)
    with bus.worker():
        for warden in wardens:
            warden.publish("localisation", {"localised": True})
        explorer.publish("hazard", hazard(0))
        wardens[0].receive(1, timeout=30)
        start = threading.Barrier(2)
        outcomes: dict[str, object] = {}

        def claim(index: int) -> None:
            start.wait()
            try:
                outcomes[f"warden{index + 1}"] = wardens[index].claim_hazard(1)["claimed_by"]
            except ServiceRefused as refused:
                outcomes[f"warden{index + 1}"] = refused

        threads = [threading.Thread(target=claim, args=(i,)) for i in range(2)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        assert set(outcomes) == {"warden1", "warden2"}, "each claim was answered"
        winners = [name for name, outcome in outcomes.items() if outcome == name]
        assert len(winners) == 1, outcomes
        (loser,) = set(outcomes) - set(winners)
        refused = outcomes[loser]
        assert isinstance(refused, ServiceRefused), outcomes
        assert str(refused).endswith(f"hazard 1 is claimed by {winners[0]}"), refused
        winner = dict(zip(("warden1", "warden2"), wardens, strict=True))[winners[0]]
        assert winner.hazard(1)["claimed_by"] == winners[0]


def test_a_service_that_is_down_times_out_clearly(bus: Bus) -> None:
    explorer, _ = team(bus)
    started = time.monotonic()
    with pytest.raises(ServiceTimeout, match="is `fleetbus worker` running"):
        explorer.hazard(1, timeout=1.0)
    assert time.monotonic() - started < 10


def test_a_bug_in_a_service_is_an_internal_error_not_the_callers_fault(
    bus: Bus, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    real = fleetbus.workers.runner.hazard_services

    def with_a_bug(hazards: Any, channels: Any) -> dict[str, Any]:
        async def broken(caller: str, params: dict[str, Any]) -> Any:
            return {}["mission"]  # a KeyError, as a bug would raise one

        return {**real(hazards, channels), "hazard.open": broken}

    monkeypatch.setattr(fleetbus.workers.runner, "hazard_services", with_a_bug)
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker() as worker, caplog.at_level(logging.ERROR, logger="fleetbus.rpc"):
        with pytest.raises(
            ServiceFailed, match=r"failed on 'hazard.open'.*reference ([0-9a-f]{12})"
        ) as failed:
            warden.open_hazards()
        with pytest.raises(ServiceRefused, match="no hazard 9"):
            warden.hazard(9)  # the caller's fault stays the caller's
        assert worker.context is not None and worker.context.rpc.internal_errors == 1
    reference = str(failed.value).rsplit(" ", 1)[-1].rstrip(")")
    [logged] = [r for r in caplog.records if reference in r.getMessage()]
    assert logged.exc_info is not None and logged.exc_info[0] is KeyError, "logged with its traceback"


def test_a_robot_is_answered_only_the_hazards_it_reported_or_that_are_open_to_it(stored_bus: Bus) -> None:
    """``hazard.get`` answers what ``hazard.open`` would give the caller, and the hazards it
    reported: not another warden's hazard, not a cleared one, not a site's; refused as any other
    request the service refuses."""
    bus = stored_bus
    explorer, (warden1, warden2) = team(bus)

    epoch = "20261128T000000000Z-0000beef"

    def event(robot: str, seq: int) -> dict[str, Any]:
        return build_event("hazard", robot, epoch, seq, hazard(seq)).model_dump(mode="json")

    async def hazards(store: Repositories) -> None:
        hazards, at = store.hazards, datetime.now(timezone.utc)
        for seq in range(3):
            await hazards.add_hazard("default", "explorer1", epoch, seq, event("explorer1", seq), at, False)
        await hazards.claim("default", 2, "warden1", at)
        await hazards.claim("default", 3, "warden1", at)
        await hazards.mark_reached("default", 3, "warden1", at)
        await hazards.mark_cleared("default", 3, "warden1", at)
        announced = HazardState.ANNOUNCED
        at_site = Hazard("default", 1, "explorer9", epoch, 0, event("explorer9", 0), announced, at)
        assert (await hazards.apply_site_hazard("site-a", at_site))[0] is SiteApplied.APPLIED

    bus.with_store(hazards)
    with bus.worker():
        assert warden2.hazard(1)["state"] == "announced", "nobody holds it: open to every robot"
        assert warden1.hazard(2)["claimed_by"] == "warden1", "its own claim"
        for robot, hazard_id in ((warden2, 2), (warden1, 3), (warden1, 4), (explorer, 4)):
            with pytest.raises(ServiceRefused, match=f"hazard {hazard_id} in mission 'default' is not open"):
                robot.hazard(hazard_id)
        reported = [explorer.hazard(hazard_id)["state"] for hazard_id in (1, 2, 3)]
        assert reported == ["announced", "claimed", "cleared"], "its reporter follows each hazard"
        with pytest.raises(ServiceRefused, match="no hazard 5 in mission 'default'"):
            warden1.hazard(5)


def test_a_reply_that_comes_after_its_call_gave_up_is_not_kept(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A service that answers after the caller's timeout: the reply reaches the robot's channel
    with no call waiting for it, and is dropped (it was kept until the connection was replaced)."""
    real = fleetbus.workers.runner.hazard_services
    slowed: list[str] = []

    def slow_once(hazards: Any, channels: Any) -> dict[str, Any]:
        services = real(hazards, channels)

        async def wardens(caller: str, params: dict[str, Any]) -> Any:
            if not slowed:
                slowed.append(caller)
                await asyncio.sleep(1.5)
            return await services["wardens"](caller, params)

        return {**services, "wardens": wardens}

    arrived: list[str] = []
    on_reply = RpcChannel._on_reply

    def seen(rpc: RpcChannel, channel: Any, method: Any, properties: Any, body: bytes) -> None:
        arrived.append(properties.correlation_id)
        on_reply(rpc, channel, method, properties, body)

    monkeypatch.setattr(fleetbus.workers.runner, "hazard_services", slow_once)
    monkeypatch.setattr(RpcChannel, "_on_reply", seen)  # before the robot's first call makes its channel
    explorer, _ = team(bus)
    with bus.worker():
        with pytest.raises(ServiceTimeout):
            explorer.wardens(timeout=0.5)
        rpc = explorer._sessions.mine().rpc  # the calling thread's
        assert rpc is not None

        def late_reply_read() -> bool:
            rpc._connection.process_data_events(time_limit=0.05)
            return bool(arrived)

        wait_for(late_reply_read, what="the late reply reaching the robot")
        assert rpc._replies == {}, "the late reply kept"
        assert explorer.wardens(timeout=10) is not None, "and the next call is answered"


def test_a_service_call_after_the_broker_closed_the_service_channel_opens_a_new_one(bus: Bus) -> None:
    """The broker may close the service channel alone (here: a publish it refuses, 403; a 404 is
    alike) and the client only learns of it at its next call, which then goes on a new channel of
    the same connection instead of failing."""
    warden = bus.robot(bus.add("warden1", kind=RobotKind.WARDEN))
    with bus.worker():
        assert [w["name"] for w in warden.wardens(timeout=30)] == ["warden1"]
        session = warden._sessions.mine()
        connection, rpc = session.connection, session.rpc
        assert connection is not None and rpc is not None
        rpc._channel.basic_publish("no-such-exchange", "x", b"{}")

        def closed_by_the_broker() -> bool:  # read here as the next call would read it first
            connection.process_data_events(0)
            return not rpc._channel.is_open

        wait_for(closed_by_the_broker, what="the broker's channel.close")
        assert [w["name"] for w in warden.wardens(timeout=30)] == ["warden1"]
        assert session.connection is connection, "the same connection, a new channel"
        assert session.rpc is not rpc
