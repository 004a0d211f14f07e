"""Fixtures: the broker the README's command starts, a fresh virtual host per test, and MongoDB.

MongoDB runs use ``FLEETBUS_MONGODB_URL`` when set, else mongoeco's MongoDB wire-protocol
server started here under Python 3.13 (the venv ``.venv-mongoeco`` that scripts/setup makes).
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from broker.accounts import fresh_vhost
from broker.endpoint import BrokerEndpoint, resolve_broker
from broker.management import ManagementAPI
from fleetbus.config import load_settings
from tests.store.mongodb import mongodb_url  # noqa: F401  (the MongoDB fixture, shared)
from tests.support import Bus


@pytest.fixture(scope="session")
def endpoint() -> BrokerEndpoint:
    """The same code path as `fleetbus broker up`: FLEETBUS_AMQP_URL, Docker, or the private node."""
    return resolve_broker(load_settings(), start=True)


@pytest.fixture(scope="session")
def management(endpoint: BrokerEndpoint) -> Iterator[ManagementAPI]:
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        yield api


@pytest.fixture
def bus(endpoint: BrokerEndpoint, management: ManagementAPI, tmp_path: Path) -> Iterator[Bus]:
    vhost = f"test-{uuid.uuid4().hex[:10]}"
    admin_url = fresh_vhost(management, endpoint.amqp_url, vhost)
    settings = replace(
        load_settings(),
        data_dir=tmp_path,
        amqp_url=admin_url,
        management_url=endpoint.management_url,
        mongodb_url=None,
    )
    test_bus = Bus(endpoint, management, vhost, settings)
    try:
        yield test_bus
    finally:
        test_bus.remove_accounts()
        management.delete_vhost(vhost)
