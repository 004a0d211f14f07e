"""What the broker itself refuses: each robot is confined to its own name."""

from __future__ import annotations

from pathlib import Path

import pika
import pika.exceptions
import pytest
import yaml

from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RobotKind
from tests.support import Bus


def _channel(url: str) -> tuple[pika.BlockingConnection, pika.adapters.blocking_connection.BlockingChannel]:
    connection = blocking_connection(url)
    return connection, connection.channel()


def _publish(url: str, exchange: str, routing_key: str, user_id: str) -> None:
    connection, channel = _channel(url)
    try:
        confirms = PipelinedConfirms(connection, channel, timeout=10)
        properties = pika.BasicProperties(delivery_mode=2, user_id=user_id, message_id="m1")
        confirms.publish([Outgoing(exchange, routing_key, b"{}", properties)], timeout=10)
    finally:
        if connection.is_open:
            connection.close()


@pytest.mark.parametrize(
    ("exchange", "routing_key", "user_id", "refusal"),
    [
        pytest.param(
            "warden1.events", "warden1.hazard", "explorer1", "ACCESS_REFUSED", id="another robot's exchange"
        ),
        pytest.param(
            "explorer1.events", "explorer1.hazard", "warden1", "PRECONDITION_FAILED", id="forged user_id"
        ),
        pytest.param(
            "explorer1.events", "warden1.hazard", "explorer1", "ACCESS_REFUSED", id="another robot's key"
        ),
    ],
)
def test_the_broker_refuses_a_robot_speaking_for_another(
    bus: Bus, exchange: str, routing_key: str, user_id: str, refusal: str
) -> None:
    explorer = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.add("warden1", kind=RobotKind.WARDEN)
    with pytest.raises(PublishRefused, match=refusal):
        _publish(explorer.amqp_url, exchange, routing_key, user_id)


def test_robot_cannot_read_bind_or_delete_another_robots_queue(bus: Bus) -> None:
    explorer = bus.add("explorer1", kind=RobotKind.EXPLORER)
    bus.add("warden1", kind=RobotKind.WARDEN)
    attempts = {
        "consume": lambda ch: ch.basic_get("warden1.inbox"),
        "bind": lambda ch: ch.queue_bind("warden1.inbox", "explorer1.events", "#"),
        "bind to notifications": lambda ch: ch.queue_bind("explorer1.inbox", "fleetbus.notify", "notify.#"),
        "delete": lambda ch: ch.queue_delete("warden1.inbox"),
        "purge": lambda ch: ch.queue_purge("warden1.inbox"),
        "read the ingest": lambda ch: ch.basic_get("fleetbus.ingest.events"),
    }
    for what, attempt in attempts.items():
        connection, channel = _channel(explorer.amqp_url)
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
            attempt(channel)
        assert refused.value.reply_code == 403, what
        connection.close()


def test_no_guest_account(bus: Bus) -> None:
    assert "guest" not in {user["name"] for user in bus.api.list_users()}


def test_compose_makes_no_guest_account() -> None:
    """RabbitMQ's image creates ``guest`` only when no default user is given; compose gives one."""
    compose = yaml.safe_load((Path(__file__).resolve().parent.parent / "compose.yaml").read_text())
    environment = compose["services"]["rabbitmq"]["environment"]
    assert environment["RABBITMQ_DEFAULT_USER"] == "fleetbus-admin"
    assert "guest" not in yaml.safe_dump(compose)
