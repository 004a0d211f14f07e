"""The administrator's step before the worker and the recorder run with their own accounts alone.

``fleetbus setup`` (and ``fleetbus broker up``) run it once per broker and virtual host; it is
idempotent, so running it again changes nothing that is in place. It makes the ``fleetbus`` and
``fleetbus-recorder`` accounts (their passwords kept in ``$FLEETBUS_DATA_DIR/accounts/``, mode
0600), the service's exchanges and queues for ``FLEETBUS_INGEST_SHARDS`` shards, and the
recorder's queue with its bindings, which ``fleetbus-recorder`` may read but not declare, and the
policies that bound the inboxes and the dead-letter queue and give every quorum queue its delivery
limit (:mod:`fleetbus.broker.policies`).
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass

from fleetbus.bounds import bounds
from fleetbus.broker.accounts import vhost_of
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.policies import apply_policies, bound_policies, central_policies, delivery_policies
from fleetbus.broker.topology import core_topology, declare_with_url, recorder_topology
from fleetbus.settings import Settings
from fleetbus.workers.recorder.runner import recorder_url
from fleetbus.workers.runner import service_url

log = logging.getLogger("fleetbus.setup")


@dataclass(frozen=True)
class ServiceAccounts:
    service_url: str
    """The workers' account, ``fleetbus``: confined to ``fleetbus.*``."""
    recorder_url: str
    """The recorder's, ``fleetbus-recorder``: reads its one queue, nothing else."""


async def set_up_service(settings: Settings, admin: BrokerEndpoint) -> ServiceAccounts:
    """As the administrator of ``admin``: the service accounts, the topology and the bindings."""
    service = await asyncio.to_thread(service_url, settings, admin)
    recorder = await asyncio.to_thread(recorder_url, settings, admin)
    await declare_with_url(
        admin.amqp_url,
        [
            core_topology(settings.ingest_shards, cluster=settings.cluster),
            recorder_topology(cluster=settings.cluster),
        ],
    )
    await asyncio.to_thread(set_queue_bounds, settings, admin)
    return ServiceAccounts(service, recorder)


def set_queue_bounds(settings: Settings, admin: BrokerEndpoint) -> None:
    limits = bounds(settings)
    with ManagementAPI.from_urls(admin.management_url, admin.amqp_url) as api:
        version = str(api.overview().get("rabbitmq_version", ""))
        apply_policies(
            api,
            vhost_of(admin.amqp_url),
            [
                *bound_policies(limits.inbox, limits.dead_letters, version, settings.cluster),
                *delivery_policies(version, settings.cluster),
                *central_policies(limits.site_reports, limits.site_downlink, limits.site_maps),
            ],
        )
