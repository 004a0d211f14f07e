"""A site's account at central writes for its own robots only: central's broker refuses the rest,
and what a site sends in another's name is refused by central's worker."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pika
import pika.exceptions
import pytest
from pika.adapters.blocking_connection import BlockingChannel

from fleetbus.broker.sites import add_site_account
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.envelope import build_event, encode_event, new_epoch
from fleetbus.schemas.routing import RobotKind, inbox_queue, site_downlink_queue, site_status_exchange
from fleetbus.workers.site_report import report_to_central
from fleetbus.workers.sites import assign_robots
from tests.factories import hazard
from tests.sites.pair import SitePair
from tests.support import wait_for


def publish_as_site(pair: SitePair, robot: str, user_id: str, key_robot: str | None = None) -> None:
    """Publish a hazard of ``user_id`` to ``robot``'s exchange at central, as the site, confirmed,
    with the routing key of ``key_robot`` (``user_id`` by default)."""
    assert pair.account is not None
    event = build_event("hazard", user_id, new_epoch(), 0, hazard(0))
    connection = blocking_connection(pair.account.amqp_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        properties = pika.BasicProperties(
            user_id=user_id, delivery_mode=2, headers={"x-shovelled": []}, content_type="application/json"
        )
        channel.basic_publish(
            f"{robot}.events",
            f"{key_robot or user_id}.hazard",
            encode_event(event),
            properties,
            mandatory=True,
        )
    finally:
        if connection.is_open:
            connection.close()


def test_a_site_cannot_write_as_robots_not_its_own_nor_as_another_site(pair: SitePair) -> None:
    pair.add_robot("explorer1", RobotKind.EXPLORER)
    pair.central.add("explorer9", kind=RobotKind.EXPLORER)  # a robot of central's, at no site
    pair.central.add("explorer8", kind=RobotKind.EXPLORER)  # a robot of another site
    asyncio.run(add_site_account(pair.central.admin_url, pair.central.api, "base2", rotate=True))
    pair.central.accounts.append("base2")
    central = pair.central
    pair.central_store(
        lambda repos: assign_robots(
            repos.sites, repos.hazards, central.api, central.admin_url, "base2", ["explorer8"]
        )
    )

    for robot in ("explorer9", "explorer8", "base2"):
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
            publish_as_site(pair, robot, robot)
        assert refused.value.reply_code == 403, f"writing to {robot}.events is refused"
    # nor read another site's downlink
    assert pair.account is not None
    connection = blocking_connection(pair.account.amqp_url)
    try:
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
            connection.channel().basic_get(site_downlink_queue("base2"))
        assert refused.value.reply_code == 403
    finally:
        if connection.is_open:
            connection.close()

    # on its own robot's exchange, another's routing key: refused by the broker (topic permissions)
    for other in ("explorer8", "base2"):
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
            publish_as_site(pair, "explorer1", other)
        assert refused.value.reply_code == 403, f"{other}'s routing key on explorer1.events is refused"

    # its own robot's exchange and key in another's name: the broker lets an impersonator set any
    # user_id, and central's worker refuses it (user, key and body do not agree)
    with pair.central.worker():
        publish_as_site(pair, "explorer1", "explorer8", key_robot="explorer1")
        publish_as_site(pair, "explorer1", "base2", key_robot="explorer1")
        publish_as_site(pair, "explorer1", "explorer1")  # the sentinel: its own, stored
        wait_for(lambda: pair.central.count() == 1, what="the site's own robot's event stored")
        letters = wait_for(lambda: len(pair.central.dead_letters()) == 2 and pair.central.dead_letters())
    assert sorted(letter.user_id or "" for letter in letters) == ["base2", "explorer8"]
    assert {letter.reason for letter in letters} == {"identity-mismatch"}
    assert [r.robot_id for r in pair.central.find()] == ["explorer1"]


def test_a_site_writes_only_its_robots_event_and_beacon_exchanges_and_its_own_reports(pair: SitePair) -> None:
    """Not its robot's inbox, commands or requests (a site would speak to a robot, or call central's
    services, in its name), nor its own downlink: only what its links send."""
    pair.add_robot("explorer1", RobotKind.EXPLORER)
    assert pair.account is not None
    status = site_status_exchange(pair.name)

    def publish(channel: BlockingChannel, exchange: str, key: str) -> None:
        channel.basic_publish(exchange, key, b"{}", pika.BasicProperties(user_id="explorer1"))

    attempts: dict[str, Callable[[BlockingChannel], object]] = {
        # its robot's commands and requests, by their exchanges
        "publish to explorer1.commands": lambda channel: publish(
            channel, "explorer1.commands", "explorer1.go"
        ),
        "publish to explorer1.requests": lambda channel: publish(
            channel, "explorer1.requests", "explorer1.x"
        ),
        # a queue bound to an exchange it may write, to write into it (write on the queue)
        "bind explorer1.inbox": lambda channel: channel.queue_bind(inbox_queue("explorer1"), status, "x"),
        "bind its downlink": lambda channel: channel.queue_bind(site_downlink_queue(pair.name), status, "x"),
    }
    refused: dict[str, int] = {}
    for what, attempt in attempts.items():
        connection = blocking_connection(pair.account.amqp_url)
        try:
            channel = connection.channel()
            channel.confirm_delivery()
            with pytest.raises(pika.exceptions.ChannelClosedByBroker) as closed:
                attempt(channel)
            refused[what] = closed.value.reply_code
        finally:
            if connection.is_open:
                connection.close()
    assert set(refused.values()) == {403}, refused
    # what its links send still goes: its robot's events, its report
    publish_as_site(pair, "explorer1", "explorer1")
    assert report_to_central(pair.site.api, pair.site.vhost, pair.name, pair.central_url)
