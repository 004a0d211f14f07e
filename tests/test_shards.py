"""Ingest shards on the real broker: where each robot's messages go, before any worker runs."""

from __future__ import annotations

import json

import pika
import pika.exceptions
import pytest

from fleetbus.broker.accounts import Role, delete_account
from fleetbus.broker.routes import RouteMap
from fleetbus.broker.shards import Move, ShardMap, apply_move, read_shard_map, rebalance_plan
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import (
    EXPRESS_QUEUE,
    INGEST_EXCHANGE,
    INGEST_QUEUE,
    SHARD_EXCHANGE,
    RobotKind,
    beacon_headers,
    ingest_shard_queue,
    shard_binding_keys,
)
from tests.factories import status
from tests.support import Bus, assert_stored_once_in_order, keys, wait_for
from tests.test_cli import fleetbus


def _queued(bus: Bus, shards: int) -> list[int]:
    return [bus.ready_messages(ingest_shard_queue(shard)) for shard in range(shards)]


def test_robots_are_spread_evenly_and_each_robots_messages_reach_only_its_shard(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=4)
    names = [f"robot{n}" for n in range(8)]
    robots = {name: bus.robot(bus.add(name, kind=RobotKind.EXPLORER)) for name in names}
    bus.add("ops1", role=Role.OPERATOR)
    shard_map = read_shard_map(bus.api, bus.vhost, 4)
    assert shard_map.load() == [2, 2, 2, 2], "least loaded first: an even spread"
    assert set(shard_map.bindings) == set(names), "robots only: an operator publishes no events"
    assert shard_map.unassigned == () and shard_map.stray() == []

    expected = [0, 0, 0, 0]
    for n, name in enumerate(names):
        robots[name].publish_many([("status", status())] * (n + 1))
        shard = shard_map.shard_of(name)
        assert shard is not None
        expected[shard] += n + 1
        wait_for(lambda: _queued(bus, 4) == expected, what=f"{name}'s events in shard {shard} only")


def test_a_robot_bound_to_no_shard_goes_to_shard_0_and_trace_shows_the_way(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=2)
    bus.add("robot-a")
    second = bus.robot(bus.add("robot-b"))
    assert read_shard_map(bus.api, bus.vhost, 2).bindings == {"robot-a": (0,), "robot-b": (1,)}
    bus.api.unbind_keys(bus.vhost, SHARD_EXCHANGE, ingest_shard_queue(1), shard_binding_keys("robot-b"))
    shard_map = read_shard_map(bus.api, bus.vhost, 2, ["robot-a", "robot-b"])
    assert shard_map.unassigned == ("robot-b",) and shard_map.shard_of("robot-b") == 0

    second.publish("status", status())
    wait_for(lambda: _queued(bus, 2) == [1, 0], what="the unassigned robot's event in shard 0")
    [route] = RouteMap.from_management(bus.api, bus.vhost).routes("robot-b.events", "robot-b.status")
    assert route.queue == INGEST_QUEUE
    assert route.via == ("robot-b.events", INGEST_EXCHANGE, SHARD_EXCHANGE, "fleetbus.ingest.unassigned")
    [bound] = RouteMap.from_management(bus.api, bus.vhost).routes("robot-a.events", "robot-a.status")
    assert bound.via == ("robot-a.events", INGEST_EXCHANGE, SHARD_EXCHANGE), "no hop more for the lanes"
    [hazard] = RouteMap.from_management(bus.api, bus.vhost).routes("robot-a.events", "robot-a.hazard")
    assert (hazard.queue, hazard.via) == (EXPRESS_QUEUE, ("robot-a.events", INGEST_EXCHANGE, SHARD_EXCHANGE))


def test_the_broker_refuses_a_beacon_under_another_robots_name(bus: Bus) -> None:
    """A robot's beacon exchange is a topic exchange whose keys topic permissions hold to the
    robot's own name: a beacon keyed for another robot is refused by the broker (the channel
    closed with ACCESS_REFUSED) and reaches no shard, not that robot's lane."""
    bus.settings = bus.settings.updated(ingest_shards=2)
    forger = bus.add("robot-a")
    bus.add("robot-b")
    assert read_shard_map(bus.api, bus.vhost, 2).bindings == {"robot-a": (0,), "robot-b": (1,)}
    properties = pika.BasicProperties(user_id="robot-a", delivery_mode=2, headers=beacon_headers("robot-a"))
    body = json.dumps({}).encode()
    connection = blocking_connection(forger.amqp_url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
            channel.basic_publish("robot-a.beacon", "robot-b.beacon", body, properties)
        assert refused.value.reply_code == 403
        assert "ACCESS_REFUSED" in refused.value.reply_text and "robot-b.beacon" in refused.value.reply_text
        # the sentinel: the same path under its own name is confirmed, so routed already (the
        # broker routes a message before it confirms it); what reached the shards is all there is
        channel = connection.channel()
        channel.confirm_delivery()
        channel.basic_publish("robot-a.beacon", "robot-a.beacon", body, properties)
    finally:
        connection.close()
    assert _queued(bus, 2) == [1, 0], "the sentinel in robot-a's shard, nothing in robot-b's"


def test_a_deleted_robot_leaves_its_shard(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=2)
    bus.add("robot-a")
    bus.add("robot-b")
    delete_account(bus.admin_url, bus.api, "robot-b")
    assert read_shard_map(bus.api, bus.vhost, 2).bindings == {"robot-a": (0,)}
    bus.add("robot-c")
    assert read_shard_map(bus.api, bus.vhost, 2).bindings == {"robot-a": (0,), "robot-c": (1,)}


def test_rebalance_places_every_robot_once_and_evens_the_load() -> None:
    current = ShardMap(
        3,
        {"a": (0,), "b": (0,), "c": (0,), "d": (0,), "e": (5,), "f": (1, 2)},
        unassigned=("g",),
    )
    moves = rebalance_plan(current)
    after = {robot: bound[0] for robot, bound in current.bindings.items() if len(bound) == 1}
    after.update({move.robot: move.target for move in moves})
    assert [after.get(r) is not None for r in "abcdefg"] == [True] * 7
    counts = [list(after.values()).count(shard) for shard in range(3)]
    assert max(counts) - min(counts) <= 1 and sum(counts) == 7
    assert Move("e", (5,), after["e"]) in moves and Move("g", (), after["g"]) in moves
    assert "a" not in {m.robot for m in moves}, "robots in place stay put, the last by name move"
    assert rebalance_plan(ShardMap(2, {"a": (0,), "b": (1,)})) == []


def test_a_move_binds_the_new_shard_before_it_unbinds_the_old(bus: Bus) -> None:
    bus.settings = bus.settings.updated(ingest_shards=2)
    bus.add("robot-a")
    bus.add("robot-b")
    apply_move(bus.api, bus.vhost, Move("robot-b", (1,), 0))
    moved = read_shard_map(bus.api, bus.vhost, 2)
    assert moved.bindings == {"robot-a": (0,), "robot-b": (0,)}
    on_zero = {b["routing_key"] for b in bus.api.exchange_bindings(bus.vhost, SHARD_EXCHANGE)}
    assert set(shard_binding_keys("robot-b")) <= on_zero, "every key of robot-b's types moved"


def _management_count(bus: Bus, shard: int) -> int:
    queue = bus.api.get_queue(bus.vhost, ingest_shard_queue(shard))
    return queue.get("messages_ready", 0) + queue.get("messages_unacknowledged", 0)


def test_more_shards_then_rebalance_from_the_command_line(bus: Bus) -> None:
    robots = {name: bus.robot(bus.add(name)) for name in ("robot-a", "robot-b", "robot-c", "robot-d")}
    sent = {name: keys(robot.publish_many([("status", status())] * 5)) for name, robot in robots.items()}
    bus.settings = bus.settings.updated(ingest_shards=2)  # the workers and the commands from now on

    listed = json.loads(fleetbus(bus, "shards", "--json").stdout)
    assert [(s["shard"], len(s["robots"]), s["worker"]) for s in listed["states"]] == [
        (0, 4, None),
        (1, 0, None),
    ]
    assert (listed["express"]["queue"], listed["express"]["worker"]) == (EXPRESS_QUEUE, None)
    dry = fleetbus(bus, "shards", "rebalance", "--dry-run")
    assert dry.returncode == 0 and "2 moves (dry run: none made)" in dry.stdout
    assert "robot-d: shard 0 -> 1" in dry.stdout
    queues = {queue["name"] for queue in bus.api.list_queues(bus.vhost)}
    assert ingest_shard_queue(1) not in queues, "a dry run declares nothing"
    wait_for(lambda: _management_count(bus, 0) == 20, what="the management API to count 20 waiting")
    refused = fleetbus(bus, "shards", "rebalance")
    assert refused.returncode == 1 and "shard 0 holds 20" in refused.stderr
    assert read_shard_map(bus.api, bus.vhost, 2).load() == [4, 0], "nothing moved"

    with bus.worker() as worker:
        wait_for(lambda: bus.count() == 20, what="the waiting events stored")
        wait_for(lambda: _management_count(bus, 0) == 0, what="the management API to see shard 0 empty")
        moved = fleetbus(bus, "shards", "rebalance")
        assert moved.returncode == 0, moved.stderr
        assert "moved 2 robots: [2, 2]" in moved.stdout
        for name, robot in robots.items():
            sent[name] += keys(robot.publish_many([("status", status())] * 5))
        wait_for(lambda: bus.count() == 40, what="the events after the move stored")
        table = fleetbus(bus, "shards")
        assert worker.context is not None and worker.context.shards.holder in table.stdout
        [express] = [line for line in table.stdout.splitlines() if EXPRESS_QUEUE in line]
        assert worker.context.shards.holder in express, "the express lane beside shard 0"
        assert "2 ingest shards, 1 live workers" in table.stdout
    for name in robots:
        assert_stored_once_in_order(bus, name, sent[name])
    assert fleetbus(bus, "shards", "rebalance").stdout.startswith("balanced: [2, 2]")
