"""What fleetbus lists through the management API is chosen by the broker: only the columns its
readers use, only the queues asked for, every page of them."""

from __future__ import annotations

import pytest

from fleetbus.broker.management import CONNECTION_COLUMNS
from fleetbus.publishers.tls import blocking_connection
from tests.support import Bus, wait_for

pytestmark = pytest.mark.rabbitmq_versions  # the management API's filters, on each release CI runs


def test_queues_named_by_a_prefix_come_from_every_page_with_their_columns_only(bus: Bus) -> None:
    wanted = [f"fleetbus.q{i}" for i in range(5)]
    # a dot in the prefix is a dot: "fleetbusXq" is not among them
    others = ["robot1.inbox", "fleetbusXq", "q.fleetbus.q9"]
    with bus.admin_channel() as channel:
        for name in wanted + others:
            channel.queue_declare(name, durable=True)
    listed = bus.api.list_queues_named(bus.vhost, "fleetbus.", ("name", "consumers"), page_size=2)
    assert sorted(queue["name"] for queue in listed) == wanted
    # only what was asked for (a queue's statistics, consumers among them, come once collected)
    assert all(set(queue) <= {"name", "consumers"} for queue in listed), listed


def test_a_connection_is_listed_with_its_user_and_since_when_only(bus: Bus) -> None:
    account = bus.add("explorer1")
    connection = blocking_connection(account.amqp_url)
    try:  # the management API shows a connection once its statistics are first collected
        listed = wait_for(lambda: bus.api.list_vhost_connections(bus.vhost), what="the connection listed")
    finally:
        connection.close()
    assert [c["user"] for c in listed] == ["explorer1"]
    assert set(listed[0]) == set(CONNECTION_COLUMNS["columns"].split(","))
