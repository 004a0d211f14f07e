"""On central: each map version it stores goes to every site but the one whose robot made it, over
the site's downlink (:class:`~fleetbus.schemas.site_changes.MapChange`, after its
:class:`~fleetbus.schemas.site_changes.MapChunk` parts when it is larger than one chunk), so the
site's robots fetch the team's newest map from their own site."""

from __future__ import annotations

import logging

import aio_pika
import aiormq.abc
from aio_pika.abc import AbstractChannel, ExchangeType

from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.routing import SITES_EXCHANGE, site_downlink_key
from fleetbus.schemas.site_changes import SITE_CHANGE_TYPE, MapChange, MapChunk
from fleetbus.workers.maps import map_image
from fleetbus.workers.store.maps import MapStore, MapVersion
from fleetbus.workers.store.sites import SiteRegistry

log = logging.getLogger("fleetbus.sites")


class SiteMapRelay:
    """Publishes a stored map version to the sites (persistent; confirmed when ``channel`` has
    publisher confirms). Called for every map event handled, redeliveries included: a site stores
    a map event's version once."""

    def __init__(self, sites: SiteRegistry, maps: MapStore, channel: AbstractChannel) -> None:
        self._sites = sites
        self._maps = maps
        self._channel = channel

    async def relay(self, version: MapVersion) -> list[str]:
        """The sites it was sent to (a site whose maps queue the broker has not is logged and left
        out: `fleetbus sites sync` makes it again)."""
        targets = [
            site for site, robots in (await self._sites.sites()).items() if version.robot_id not in robots
        ]
        if not targets:
            return []
        changes = downlink_map(version, await map_image(self._maps, version))
        exchange = await self._channel.declare_exchange(SITES_EXCHANGE, ExchangeType.TOPIC, durable=True)
        sent = []
        for site in sorted(targets):
            for n, change in enumerate(changes):  # in order: the chunks before the change that commits them
                message = aio_pika.Message(
                    change.model_dump_json().encode(),
                    delivery_mode=aio_pika.DeliveryMode.PERSISTENT,
                    content_type="application/json",
                    type=SITE_CHANGE_TYPE,
                    # aiormq matches a returned message to its publish by its id
                    message_id=f"map:{version.robot_id}:{version.version}:{site}:{n}",
                )
                taken = await exchange.publish(
                    message, routing_key=site_downlink_key(site, change.change), mandatory=True
                )
                if isinstance(taken, aiormq.abc.DeliveredMessage):  # returned: no queue took it
                    log.error(
                        "map %d of %s not sent to site %s: central's broker has no maps queue bound for it "
                        "(`fleetbus sites sync` makes it)",
                        version.version,
                        version.robot_id,
                        site,
                    )
                    break
            else:
                sent.append(site)
        return sent


def downlink_map(
    version: MapVersion, image: bytes, chunk_bytes: int = MAP_CHUNK_BYTES
) -> list[MapChunk | MapChange]:
    """The downlink messages of a map version: the change with the image in it, or, for an image
    larger than ``chunk_bytes``, its chunks and then the change that names them."""
    change = {
        "robot_id": version.robot_id,
        "epoch": version.epoch,
        "seq": version.seq,
        "metadata": version.metadata,
        "created_at": version.created_at,
        "sha256": version.sha256,
    }
    if len(image) <= chunk_bytes:
        return [MapChange(**change, pgm=image)]
    map_id = f"downlink:{version.robot_id}:{version.epoch}:{version.seq}"
    chunks: list[MapChunk | MapChange] = [
        MapChunk(map_id=map_id, index=index, data=image[start : start + chunk_bytes])
        for index, start in enumerate(range(0, len(image), chunk_bytes))
    ]
    return [*chunks, MapChange(**change, map_id=map_id, chunks=len(chunks))]
