"""Whether the suite reaches its brokers over TLS, and the certificates its nodes serve."""

from __future__ import annotations

import os

from fleetbus.broker.certificates import TlsFiles
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.settings import load_settings
from fleetbus_dev.local_node import NodeInfo

#: The suite reaches its brokers over TLS: AMQPS, and the management API over HTTPS, each verified
#: with the run's CA (``FLEETBUS_TEST_TLS=0``: plain AMQP and HTTP). Every node the suite starts
#: serves the certificates of the project's data folder, so one CA verifies them all.
BROKER_TLS = os.environ.get("FLEETBUS_TEST_TLS", "1") != "0"


def run_tls_files() -> TlsFiles:
    """The certificates every node of the run serves (those of ``fleetbus broker up``'s node)."""
    return TlsFiles.for_settings(load_settings())


def suite_endpoint(info: NodeInfo) -> BrokerEndpoint:
    """A node of the suite as administrator: over TLS (see ``BROKER_TLS``), robots handed its AMQPS
    URL; or over plain AMQP (a TLS-only node's URLs are its TLS ones either way)."""
    if BROKER_TLS:
        assert info.amqps_url and info.management_tls_url, f"the node serves no TLS: {info}"
        return BrokerEndpoint(info.amqps_url, info.management_tls_url, "private", info.public_url)
    return plain_endpoint(info)


def plain_endpoint(info: NodeInfo) -> BrokerEndpoint:
    """A node as administrator over plain AMQP and HTTP."""
    assert info.amqp_url and info.management_url
    return BrokerEndpoint(info.amqp_url, info.management_url, "private")
