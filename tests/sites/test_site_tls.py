"""sslyze against a site's broker node: its AMQPS and management HTTPS listeners accept TLS 1.2 and
1.3 with forward-secret AEAD suites only, and serve a certificate that verifies against its CA
for the names robots and central's links are told to use."""

from __future__ import annotations

from pathlib import Path

from fleetbus_dev.local_node import LocalNode
from tests.peers.tls_scan import Listener, assert_profile, scan


def test_a_sites_node_accepts_only_the_tls_profile(site_node: LocalNode, tmp_path: Path) -> None:
    ports = site_node.status().ports
    listeners = [
        Listener("site node AMQPS", ports["amqps"], site_node.tls.ca),
        Listener("site node management HTTPS", ports["management_tls"], site_node.tls.ca),
    ]
    assert_profile(scan(listeners, tmp_path))
