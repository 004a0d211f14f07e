"""sslyze against every node of the three-node cluster: each node's AMQPS and management HTTPS
listeners accept TLS 1.2 and 1.3 with forward-secret AEAD suites only, and serve a certificate
that verifies against the cluster's CA for the names robots are told to use."""

from __future__ import annotations

from pathlib import Path

from fleetbus_dev.cluster import LocalCluster
from tests.peers.tls_scan import Listener, assert_profile, scan


def test_every_cluster_node_accepts_only_the_tls_profile(cluster: LocalCluster, tmp_path: Path) -> None:
    cluster.up(timeout=300)  # every node, whatever an earlier test left down
    listeners = []
    for number, node in enumerate(cluster.nodes, 1):
        ports = node.ports()
        assert ports is not None
        listeners += [
            Listener(f"cluster node {number} AMQPS", ports["amqps"], cluster.tls.ca),
            Listener(f"cluster node {number} management HTTPS", ports["management_tls"], cluster.tls.ca),
        ]
    assert_profile(scan(listeners, tmp_path))
