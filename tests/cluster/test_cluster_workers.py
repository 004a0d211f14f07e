"""Worker processes scale out on the cluster: each connected to another node first, they share the
ingest shards, and the shards of one killed with SIGKILL go to the others within 10 s."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid

import pytest

from fleetbus.broker.urls import without_password
from fleetbus.publishers.addresses import join_addresses, split_addresses
from fleetbus.workers.shards import share
from tests.cluster.test_cluster_failover import drain_and_check, stop_worker
from tests.support import Bus, Publishing, wait_for

SHARDS = 4
#: The bar for a dead worker's shards to be consumed by the others.
TAKEOVER_S = 10.0


def spawn_worker_on(bus: Bus, first_node: int) -> subprocess.Popen[bytes]:
    """``fleetbus worker`` whose service URL lists the cluster's nodes starting with ``first_node``
    (as workers on different machines would each list their nearest node first)."""
    addresses = split_addresses(bus.service_accounts().service_url)
    rotated = addresses[first_node:] + addresses[:first_node]
    env = bus.service_env()
    env["FLEETBUS_SERVICE_URL"] = without_password(join_addresses(rotated))
    log = open(bus.settings.data_dir / f"worker-{uuid.uuid4().hex[:6]}.log", "wb")
    command = [sys.executable, "-m", "fleetbus", "worker", "--no-recorder"]
    return subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)


@pytest.mark.parametrize("count", [2, 4], ids=["2-workers", "4-workers"])
def test_workers_on_different_nodes_share_the_shards_and_take_over_a_killed_ones(
    cluster_bus: Bus, count: int
) -> None:
    bus = cluster_bus
    bus.settings = bus.settings.updated(ingest_shards=SHARDS)
    robots = [bus.robot(bus.add(f"explorer{n}")) for n in range(4)]
    workers = [spawn_worker_on(bus, n % 3) for n in range(count)]
    try:
        expected = sorted(share(SHARDS, [str(n) for n in range(count)], str(n)) for n in range(count))
        wait_for(
            lambda: sorted(bus.shard_holders().values()) == expected, timeout=120, what=f"{expected} shards"
        )
        publishing = [Publishing(robot, period=0.02, hazard_every=10).start() for robot in robots]
        wait_for(lambda: bus.count() >= 200, timeout=60, what="200 events stored")
        victim = workers.pop(0)
        victim.kill()
        killed_at = time.monotonic()
        assert victim.wait(10) == -9
        survivors = sorted(
            share(SHARDS, [str(n) for n in range(count - 1)], str(n)) for n in range(count - 1)
        )
        wait_for(
            lambda: sorted(bus.shard_holders().values()) == survivors,
            timeout=60,
            interval=0.1,
            what=f"the survivors holding {survivors}",
        )
        takeover = time.monotonic() - killed_at
        print(f"{count} workers: the killed worker's shards taken over in {takeover:.1f} s")
        drain_and_check(bus, publishing)
        assert all(worker.poll() is None for worker in workers), "the survivors run on"
    finally:
        for worker in workers:
            stop_worker(worker)
    assert takeover <= TAKEOVER_S, f"the dead worker's shards were taken over in {takeover:.1f} s"
