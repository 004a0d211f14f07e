"""The service layer's rules, enforced by the broker itself: an operator reaches only the robots it
mounted, nobody touches another's queue, and the broker logs every refusal it makes.

(The HTTP side, expired tokens and a guest calling an admin endpoint, is in tests/api/test_auth.py;
a robot speaking for another, with another's exchange, key or user_id, in tests/test_security.py.)"""

from __future__ import annotations

from collections.abc import Callable

import pika
import pika.exceptions
import pytest
from pika.adapters.blocking_connection import BlockingChannel

from fleetbus.broker.accounts import Role
from fleetbus.broker.mounts import bind_all, mount_bindings, unbind_all
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import PublishRefused
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import RobotKind
from fleetbus_dev.local_node import LocalNode
from tests.support import Bus, wait_for

Attempt = Callable[[BlockingChannel], object]


def refused(url: str, attempt: Attempt) -> int:
    """The reply code the broker closed the channel with (the attempt must be refused)."""
    connection = blocking_connection(url)
    try:
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as closed:
            attempt(connection.channel())
        return closed.value.reply_code
    finally:
        if connection.is_open:
            connection.close()


def test_an_operator_cannot_reach_a_robot_it_has_not_mounted(bus: Bus) -> None:
    operator = bus.add("oper1", Role.OPERATOR)
    bus.add("explorer1", kind=RobotKind.EXPLORER)
    attempts: dict[str, Attempt] = {
        "consume the robot's commands": lambda ch: ch.basic_get("explorer1.commands"),
        "consume the robot's inbox": lambda ch: ch.basic_get("explorer1.inbox"),
        "bind its stream to the robot's events": lambda ch: ch.queue_bind(
            "oper1.stream", "explorer1.events", "#"
        ),
        "bind the robot's commands to its exchange": lambda ch: ch.queue_bind(
            "explorer1.commands", "oper1.commands", "#"
        ),
        "publish straight to the robot's events": lambda ch: (
            ch.basic_publish(
                "explorer1.events", "explorer1.status", b"{}", pika.BasicProperties(user_id="oper1")
            )
            or ch.queue_declare("oper1.probe", exclusive=True)
        ),  # a round trip, so the refusal arrives
    }
    for what, attempt in attempts.items():
        assert refused(operator.amqp_url, attempt) == 403, what
    # a command goes nowhere until the service mounts the robot
    connection = blocking_connection(operator.amqp_url)
    confirms = PipelinedConfirms(connection, connection.channel(), timeout=10)
    command = Outgoing(
        "oper1.commands", "explorer1.stop", b"{}", pika.BasicProperties(user_id="oper1", message_id="c1")
    )
    with pytest.raises(PublishRefused, match="unroutable"):
        confirms.publish([command], 10)
    bind_all(bus.api, bus.vhost, mount_bindings("explorer1", "oper1"))  # what a mount does
    confirms = PipelinedConfirms(connection, connection.channel(), timeout=10)
    confirms.publish([command], 10)
    unbind_all(bus.api, bus.vhost, mount_bindings("explorer1", "oper1"))  # and an unmount undoes
    with pytest.raises(PublishRefused, match="unroutable"):
        PipelinedConfirms(connection, connection.channel(), timeout=10).publish([command], 10)
    connection.close()


def test_a_user_cannot_declare_or_bind_another_users_queue(bus: Bus) -> None:
    alice = bus.add("alice", Role.OPERATOR)
    bus.add("bob", Role.OPERATOR)
    attempts: dict[str, Attempt] = {
        "declare a queue in bob's name": lambda ch: ch.queue_declare("bob.mine", durable=True),
        "declare an exchange in bob's name": lambda ch: ch.exchange_declare("bob.feed", "topic"),
        "bind bob's stream": lambda ch: ch.queue_bind("bob.stream", "alice.commands", "#"),
        "bind bob's inbox to her events": lambda ch: ch.queue_bind("bob.inbox", "alice.events", "#"),
        "bind her queue to bob's commands": lambda ch: ch.queue_bind("alice.inbox", "bob.commands", "#"),
        "delete bob's stream": lambda ch: ch.queue_delete("bob.stream"),
        "read bob's stream": lambda ch: ch.basic_get("bob.inbox"),
        "declare a queue outside any name": lambda ch: ch.queue_declare("shared", durable=True),
    }
    for what, attempt in attempts.items():
        assert refused(alice.amqp_url, attempt) == 403, what
    connection = blocking_connection(alice.amqp_url)
    connection.channel().queue_declare("alice.scratch", exclusive=True)  # her own name: allowed
    connection.close()


def test_the_broker_logs_each_refusal(bus: Bus, broker_node: LocalNode | None) -> None:
    if broker_node is None:
        pytest.skip("the broker's log is read from the private node's folder; this broker's log is elsewhere")
    operator = bus.add("oper1", Role.OPERATOR)
    bus.add("explorer1", kind=RobotKind.EXPLORER)
    refused(operator.amqp_url, lambda ch: ch.basic_get("explorer1.commands"))
    refused(operator.amqp_url, lambda ch: ch.queue_bind("oper1.stream", "explorer1.events", "#"))
    expected = [
        f"access to queue 'explorer1.commands' in vhost '{bus.vhost}' refused for user 'oper1'",
        f"access to exchange 'explorer1.events' in vhost '{bus.vhost}' refused for user 'oper1'",
    ]

    def logged() -> bool:
        text = broker_node.node_log.read_text(errors="replace")
        return all(line in text for line in expected)

    wait_for(logged, timeout=10, what=f"the refusals in {broker_node.node_log}")
