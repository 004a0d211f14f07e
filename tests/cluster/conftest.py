"""A three-node RabbitMQ cluster shared by the cluster tests of this process (they all run on one
xdist worker: ``tests/conftest.py``), and a fresh virtual host on it per test.

The cluster lives in the test run's temporary folder; a test that stops or kills a node starts it
again at the end (``cluster_bus``), so each test begins with all three nodes running.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus_dev.cluster import LocalCluster
from tests.support import Bus, fresh_bus

#: Nodes in the test cluster: the smallest that keeps a majority with one node gone.
NODES = 3


@pytest.fixture(scope="session")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalCluster]:
    local = LocalCluster(tmp_path_factory.mktemp("cluster") / "cluster", NODES)
    try:
        local.up(timeout=300)
        yield local
    finally:
        for index in range(NODES):
            local.kill(index)  # throwaway nodes: no need for clean shutdowns' seconds
        local.down()  # the shared epmd


def endpoint_of(cluster: LocalCluster, management_node: int = 0) -> BrokerEndpoint:
    info = cluster.status()
    management = cluster.management_url(management_node)
    assert info.amqp_url and management
    return BrokerEndpoint(info.amqp_url, management, "private")


def management_of(cluster: LocalCluster, node: int) -> ManagementAPI:
    """The management API of one node (each answers for the whole cluster)."""
    endpoint = endpoint_of(cluster, node)
    return ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url)


@pytest.fixture
def cluster_bus(cluster: LocalCluster, tmp_path: Path) -> Iterator[Bus]:
    """A fresh virtual host on the cluster with ``FLEETBUS_CLUSTER`` set (quorum queues); every
    node running before and after."""
    cluster.up(timeout=300)
    endpoint = endpoint_of(cluster)
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        with fresh_bus(endpoint, api, tmp_path, prefix="cluster") as bus:
            bus.settings = bus.settings.updated(cluster=True)
            try:
                yield bus
            finally:
                cluster.up(timeout=300)  # a node a failed test left down: back, so its vhost can go
