"""The broker the command line uses: the configured one, else the one the development tooling
keeps for this data folder (Docker's, or a private RabbitMQ node), when that tooling is installed.

A configured broker (``FLEETBUS_AMQP_URL`` and friends) is the only one ever used
(:func:`fleetbus.broker.endpoint.external_endpoint`). The fallback is found through the
``fleetbus.local_broker`` entry point, so that the runtime wheel carries no node supervisor: a
deployment configures its broker, a checkout installs ``dev/`` (``scripts/setup`` does).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from importlib.metadata import entry_points
from typing import Protocol

from fleetbus.broker.endpoint import BrokerEndpoint, BrokerUnavailable, external_endpoint
from fleetbus.settings import Settings

GROUP = "fleetbus.local_broker"

NONE_CONFIGURED = (
    "no broker is configured: set FLEETBUS_AMQP_URL to the broker's administrator URL "
    "(a checkout's development tooling, `pip install -e dev`, adds a private node instead)"
)


class LocalBroker(Protocol):
    """What the development tooling offers when no broker is configured."""

    def resolve(self, settings: Settings, start: bool) -> BrokerEndpoint:
        """The broker as administrator; started unless ``start`` is False (then one that does not
        run is :class:`BrokerUnavailable`)."""
        ...

    def public_url(self, settings: Settings) -> str | None:
        """The address robots are handed, from the node's state alone (nothing started); None
        before the node first ran."""
        ...

    def enable_plugins(self, settings: Settings, plugins: Sequence[str]) -> None:
        """Enable RabbitMQ ``plugins`` on the private node."""
        ...


@functools.cache
def local_broker() -> LocalBroker | None:
    """The installed fallback, or None when only the runtime is installed."""
    for found in entry_points(group=GROUP):
        broker: LocalBroker = found.load()
        return broker
    return None


def require_local_broker() -> LocalBroker:
    local = local_broker()
    if local is None:
        raise BrokerUnavailable(NONE_CONFIGURED)
    return local


def resolve_broker(settings: Settings, start: bool = True) -> BrokerEndpoint:
    """The configured broker, else the development tooling's (see the module docstring)."""
    endpoint = external_endpoint(settings)
    if endpoint is not None:
        return endpoint
    return require_local_broker().resolve(settings, start)
