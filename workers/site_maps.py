"""On central: each map version it stores goes to every site but the one whose robot made it, over
the site's downlink (:class:`~fleetbus.schemas.site_changes.MapChange`), so the site's robots fetch
the team's newest map from their own site."""

from __future__ import annotations

import aio_pika
from aio_pika.abc import AbstractChannel, ExchangeType

from fleetbus.schemas.routing import SITES_EXCHANGE, site_downlink_key
from fleetbus.schemas.site_changes import SITE_CHANGE_TYPE, MapChange
from fleetbus.workers.maps import map_image
from fleetbus.workers.store.maps import MapStore, MapVersion
from fleetbus.workers.store.sites import SiteRegistry


class SiteMapRelay:
    """Publishes a stored map version to the sites (persistent; confirmed when ``channel`` has
    publisher confirms). Called for every map event handled, redeliveries included: a site stores
    a map event's version once."""

    def __init__(self, sites: SiteRegistry, maps: MapStore, channel: AbstractChannel) -> None:
        self._sites = sites
        self._maps = maps
        self._channel = channel

    async def relay(self, version: MapVersion) -> list[str]:
        """The sites it was sent to."""
        targets = [
            site for site, robots in (await self._sites.sites()).items() if version.robot_id not in robots
        ]
        if not targets:
            return []
        change = MapChange(
            robot_id=version.robot_id,
            epoch=version.epoch,
            seq=version.seq,
            metadata=version.metadata,
            created_at=version.created_at,
            sha256=version.sha256,
            pgm=await map_image(self._maps, version),
        )
        body = change.model_dump_json().encode()
        exchange = await self._channel.declare_exchange(SITES_EXCHANGE, ExchangeType.TOPIC, durable=True)
        for site in sorted(targets):
            message = aio_pika.Message(
                body,
                delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
                content_type="application/json",
                type=SITE_CHANGE_TYPE,
            )
            await exchange.publish(message, routing_key=site_downlink_key(site, change.change))
        return sorted(targets)
