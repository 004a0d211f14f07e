"""Sites and central on the broker: the uplink and downlink shovels, and each site's account at
central.

A site runs a whole fleetbus of its own; RabbitMQ forwards it to central:

* **uplink** (on the site): three durable queues, one per class of event
  (:mod:`fleetbus.broker.uplink`: hazards, events, telemetry), bound to ``fleetbus.ingest`` by
  ``<robot>.<type>`` for each robot central sent the site (:func:`forward_robot`), keep a copy of
  every event of theirs the site's broker accepted (beacons that passed the header check
  included), each bounded by a policy of its own: hazards and events refuse new ones when full
  (they stay in the robots' outboxes), telemetry drops its oldest. A dynamic shovel per class
  moves each to central in order, acking a message only once central confirmed it (``ack-mode:
  on-confirm``), so a hazard never waits behind telemetry. They name no destination exchange, so
  central receives each message on the exchange the robot published it to, with the robot's
  routing key and properties, ``user_id`` included: the site logs in to central as its own
  account, tagged ``impersonator``, which RabbitMQ lets publish with another user's ``user_id``.
* **downlink** (central to site): central publishes what a site needs (its robots' accounts, its
  missions, the team's maps) to ``fleetbus.sites`` with keys ``<site>.<kind>``;
  ``<site>.downlink`` holds the site's accounts and missions, ``<site>.downlink.maps`` its maps,
  until the shovels ``fleetbus-downlink`` and ``fleetbus-downlink-maps``, running on the site,
  move them into the site's ``fleetbus.downlink``, where :mod:`fleetbus.workers.downlink` applies
  them (what it cannot parse it moves to ``fleetbus.downlink.rejected``). Two queues, so that a
  large map on its way does not hold a mission back.
* **hazard states** (on the site): the site's worker puts each new state of its hazards in
  ``fleetbus.hazard-uplink`` (:mod:`fleetbus.workers.hazard_uplink`); the shovel
  ``fleetbus-hazard-uplink`` moves them, confirmed, to the site's ``<site>.hazards`` at central,
  whose ``fleetbus.site-hazards`` central's worker applies (:mod:`fleetbus.workers.site_hazards`).
  A shovel of its own: an exchange central lacks (a central older than its site) stops it alone,
  never the events' uplink.

At central, a site's account may configure and read only ``<site>.*`` and write only to its own
robots' exchanges, its own ``<site>.status`` (its reports, :mod:`fleetbus.workers.site_report`)
and ``<site>.hazards`` (:func:`site_permissions`): the broker refuses anything else.
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Collection, Mapping
from typing import Any
from urllib.parse import quote

from aio_pika.abc import ExchangeType

from fleetbus.broker.accounts import Account, Role, url_for, vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.policies import apply_policies, downlink_rejected_policy, uplink_policies
from fleetbus.broker.tls import shovel_uris
from fleetbus.broker.topology import (
    BindingSpec,
    ExchangeSpec,
    QueueSpec,
    Topology,
    core_topology,
    declare_with_url,
    inbox_bindings,
    replicated,
)
from fleetbus.broker.uplink import BY_QUEUE, CLASSES, UplinkBounds
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import (
    DEAD_LETTER_EXCHANGE,
    DOWNLINK_MAPS_SHOVEL,
    DOWNLINK_QUEUE,
    DOWNLINK_REJECTED_QUEUE,
    DOWNLINK_SHOVEL,
    HAZARD_UPLINK_QUEUE,
    HAZARD_UPLINK_SHOVEL,
    INGEST_EXCHANGE,
    NOTIFY_EXCHANGE,
    SITE_HAZARDS_QUEUE,
    SITE_REPORTS_QUEUE,
    SITES_EXCHANGE,
    UPLINK_QUEUE,
    RobotKind,
    beacon_exchange,
    events_exchange,
    inbox_queue,
    owner_pattern,
    site_downlink_key,
    site_downlink_queue,
    site_hazards_exchange,
    site_maps_queue,
    site_status_exchange,
)

#: The downlink's kinds of change (:mod:`fleetbus.schemas.site_changes`): small ones in one queue,
#: maps in another, each with its shovel.
DOWNLINK_KINDS = ("account", "account_removed", "robots", "mission")
MAP_KINDS = ("map", "map_chunk")
#: The tag that lets a site's account publish its robots' events with their own ``user_id``.
SITE_TAGS = "impersonator"
#: Central's queue of the sites' hazard states: what its worker refuses goes to the dead letters.
SITE_HAZARDS_QUEUE_ARGUMENTS = {"x-queue-type": "classic", "x-dead-letter-exchange": DEAD_LETTER_EXCHANGE}


# --------------------------------------------------------------------------- on the site


def site_topology() -> Topology:
    """The uplink classes', downlink and hazard uplink queues; the uplinks' bounds are policies
    (:func:`~fleetbus.broker.policies.uplink_policies`), so that changing them needs no new queue."""
    return Topology(
        queues=(
            *(QueueSpec(uplink.queue, {"x-queue-type": "classic"}) for uplink in CLASSES),
            QueueSpec(DOWNLINK_QUEUE, {"x-queue-type": "classic"}),
            QueueSpec(DOWNLINK_REJECTED_QUEUE, {"x-queue-type": "classic"}),
            QueueSpec(HAZARD_UPLINK_QUEUE, {"x-queue-type": "classic"}),
        ),
    )


def forward_robot(api: ManagementAPI, vhost: str, robot: str) -> None:
    """Forward ``robot``'s events to central from now on: its bindings into the uplink's classes,
    one per event type. Only robots central knows are bound (``fleetbus site apply`` binds each
    account central sends): an event of a robot central does not know would be refused there and
    stop its class's uplink for everyone. A binding of an older site (``<robot>.#``, everything
    into one queue) is removed."""
    for uplink in CLASSES:
        for key in uplink.keys(robot):
            api.bind(vhost, INGEST_EXCHANGE, uplink.queue, key)
    api.unbind_keys(vhost, INGEST_EXCHANGE, UPLINK_QUEUE, [f"{robot}.#"])


def stop_forwarding(api: ManagementAPI, vhost: str, robot: str) -> None:
    """No longer forward ``robot``'s events (its account at the site is removed)."""
    for uplink in CLASSES:
        api.unbind_keys(vhost, INGEST_EXCHANGE, uplink.queue, uplink.keys(robot))
    api.unbind_keys(vhost, INGEST_EXCHANGE, UPLINK_QUEUE, [f"{robot}.#"])


def forwarded_robots(api: ManagementAPI, vhost: str) -> set[str]:
    """The robots whose events the uplink takes."""
    return {
        b["routing_key"].split(".", 1)[0]
        for b in api.exchange_bindings(vhost, INGEST_EXCHANGE)
        if b["destination"] in BY_QUEUE and b["destination_type"] == "queue"
    }


def local_uri(vhost: str) -> str:
    """The site's own broker as a shovel reaches it: RabbitMQ's direct connection, no network."""
    return "amqp:///" + quote(vhost, safe="")


def _confirmed_shovel(
    source: str | list[str], destination: str | list[str], reconnect_delay_s: int, **ends: Any
) -> dict[str, Any]:
    """A shovel as fleetbus runs each of its links: AMQP 0-9-1 at both ends, a message acked at
    its source only once the destination confirmed it, and tried again every
    ``reconnect_delay_s`` while the other side is away; ``ends`` names the queues and exchanges.
    An end given as a list is a cluster's nodes, one URI each."""
    return {
        "src-protocol": "amqp091",
        "src-uri": source,
        "dest-protocol": "amqp091",
        "dest-uri": destination,
        **{key.replace("_", "-"): value for key, value in ends.items()},
        "ack-mode": "on-confirm",
        "reconnect-delay": reconnect_delay_s,
    }


def uplink_shovel(
    central_url: str, vhost: str, reconnect_delay_s: int, prefetch: int, queue: str = UPLINK_QUEUE
) -> dict[str, Any]:
    """The definition of the uplink class of ``queue``. An ``amqps://`` ``central_url`` is verified
    as fleetbus's own clients verify (:func:`~fleetbus.broker.tls.shovel_uris`: certificate and host
    name). No destination exchange: each message goes to the exchange it was published to, with
    its key."""
    return _confirmed_shovel(
        local_uri(vhost),
        shovel_uris(central_url),
        reconnect_delay_s,
        src_queue=queue,
        src_prefetch_count=prefetch,
        dest_add_forward_headers=True,
    )


def downlink_shovel(
    central_url: str, site: str, vhost: str, reconnect_delay_s: int, maps: bool = False
) -> dict[str, Any]:
    """The downlink of the site's accounts and missions, or (``maps``) of its maps."""
    return _confirmed_shovel(
        shovel_uris(central_url),
        local_uri(vhost),
        reconnect_delay_s,
        src_queue=site_maps_queue(site) if maps else site_downlink_queue(site),
        dest_queue=DOWNLINK_QUEUE,
    )


def hazard_uplink_shovel(central_url: str, site: str, vhost: str, reconnect_delay_s: int) -> dict[str, Any]:
    """The hazard states' way to central: into the site's own ``<site>.hazards`` there."""
    return _confirmed_shovel(
        local_uri(vhost),
        shovel_uris(central_url),
        reconnect_delay_s,
        src_queue=HAZARD_UPLINK_QUEUE,
        dest_exchange=site_hazards_exchange(site),
    )


async def start_site_links(
    admin_url: str,
    api: ManagementAPI,
    site: str,
    central_url: str,
    *,
    bounds: UplinkBounds,
    rejected_max: int,
    reconnect_delay_s: int,
    prefetch: int = 1000,
) -> None:
    """On the site's broker, as its administrator: the uplink classes', downlink and hazard uplink
    queues and shovels (idempotent; a new ``central_url`` replaces the old one); ``rejected_max``:
    the bound of what the downlink could not apply (:func:`downlink_rejected_policy`)."""
    validate_name(site)
    # the ingest exchange first (declaring what exists changes nothing; one shard is what it needs)
    vhost = vhost_of(admin_url)
    apply_policies(api, vhost, [*uplink_policies(bounds), downlink_rejected_policy(rejected_max)])
    await declare_with_url(admin_url, [core_topology(1), site_topology()])
    for uplink in CLASSES:
        api.put_shovel(
            vhost, uplink.shovel, uplink_shovel(central_url, vhost, reconnect_delay_s, prefetch, uplink.queue)
        )
    api.put_shovel(vhost, DOWNLINK_SHOVEL, downlink_shovel(central_url, site, vhost, reconnect_delay_s))
    api.put_shovel(
        vhost, DOWNLINK_MAPS_SHOVEL, downlink_shovel(central_url, site, vhost, reconnect_delay_s, maps=True)
    )
    api.put_shovel(
        vhost, HAZARD_UPLINK_SHOVEL, hazard_uplink_shovel(central_url, site, vhost, reconnect_delay_s)
    )


def stop_site_links(api: ManagementAPI, vhost: str) -> None:
    """Delete the shovels; the queues (and what waits in them) stay."""
    for uplink in CLASSES:
        api.delete_shovel(vhost, uplink.shovel)
    api.delete_shovel(vhost, DOWNLINK_SHOVEL)
    api.delete_shovel(vhost, DOWNLINK_MAPS_SHOVEL)
    api.delete_shovel(vhost, HAZARD_UPLINK_SHOVEL)


# --------------------------------------------------------------------------- on central


def site_permissions(site: str, robots: Collection[str]) -> tuple[str, str, str]:
    """(configure, write, read) of a site's account at central: its own ``<site>.*`` (its
    downlink queue), and writing to exactly its robots' ``<robot>.events`` and ``<robot>.beacon``
    and its own ``<site>.status`` and ``<site>.hazards``: not a robot's inbox, commands or
    requests (a site calls no service of central's in a robot's name)."""
    own = f"^{re.escape(site)}\\."
    names = "|".join(re.escape(name) for name in sorted(robots))
    robots_exchanges = [f"({names})\\.(events|beacon)"] if robots else []
    write = "|".join([*robots_exchanges, f"{re.escape(site)}\\.(status|hazards)"])
    return own, f"^({write})$", own


def central_site_topology(site: str, cluster: bool = False) -> Topology:
    """The site's downlink queue, its status exchange into the reports queue, and its hazards
    exchange into the hazard states' queue (replicated on a cluster, as the worker declares it:
    a state the broker confirmed to the site's shovel must not be lost with a node)."""
    queue = site_downlink_queue(site)
    maps = site_maps_queue(site)
    status = site_status_exchange(site)
    hazards = site_hazards_exchange(site)
    return Topology(
        exchanges=(
            ExchangeSpec(SITES_EXCHANGE, ExchangeType.TOPIC),
            ExchangeSpec(status, ExchangeType.FANOUT),
            ExchangeSpec(hazards, ExchangeType.FANOUT),
        ),
        queues=(
            QueueSpec(queue, {"x-queue-type": "classic"}),
            QueueSpec(maps, {"x-queue-type": "classic"}),
            QueueSpec(SITE_REPORTS_QUEUE, {"x-queue-type": "classic"}),
            QueueSpec(SITE_HAZARDS_QUEUE, replicated(SITE_HAZARDS_QUEUE_ARGUMENTS, cluster)),
        ),
        bindings=(
            *(BindingSpec(SITES_EXCHANGE, queue, site_downlink_key(site, kind)) for kind in DOWNLINK_KINDS),
            *(BindingSpec(SITES_EXCHANGE, maps, site_downlink_key(site, kind)) for kind in MAP_KINDS),
            BindingSpec(status, SITE_REPORTS_QUEUE, ""),
            BindingSpec(hazards, SITE_HAZARDS_QUEUE, ""),
        ),
    )


async def add_site_account(
    admin_url: str, api: ManagementAPI, site: str, *, rotate: bool = False, cluster: bool = False
) -> Account:
    """Central's account for ``site`` (a new password each time, like ``fleetbus users add``) and
    its downlink queue. Its robots are granted by :func:`grant_site_robots`."""
    validate_name(site)
    if api.get_user(site) is not None and not rotate:
        raise ValueError(f"the account {site!r} exists at central; use --rotate to give it a new password")
    password = secrets.token_urlsafe(24)
    api.put_user(site, password, SITE_TAGS)
    vhost = vhost_of(admin_url)
    grant_site_robots(api, vhost, site, ())
    await declare_with_url(admin_url, [central_site_topology(site, cluster)])
    # a site added before maps had a queue of their own took everything by one binding
    api.unbind_keys(vhost, SITES_EXCHANGE, site_downlink_queue(site), [f"{site}.#"])
    return Account(site, Role.SERVICE, url_for(admin_url, site, password))


def grant_site_robots(
    api: ManagementAPI,
    vhost: str,
    site: str,
    robots: Collection[str],
    returning: Mapping[str, RobotKind | None] | None = None,
) -> None:
    """Let ``site`` write for exactly ``robots``. At central the inboxes of robots that live at a
    site take no notifications (the site notifies them; theirs at central would fill and never
    drain): they are unbound from ``fleetbus.notify``; those of ``returning`` robots (that left
    their site, with their kinds) are bound again."""
    configure, write, read = site_permissions(site, robots)
    api.put_permissions(vhost, site, configure=configure, write=write, read=read)
    notified: dict[str, list[str]] = {}  # each inbox's keys on fleetbus.notify, listed once
    for b in api.exchange_bindings(vhost, NOTIFY_EXCHANGE):
        if b["destination_type"] == "queue":
            notified.setdefault(b["destination"], []).append(b["routing_key"])
    for robot in robots:
        # on a robot's exchanges, only that robot's routing keys (as the robot itself may)
        for exchange in (events_exchange(robot), beacon_exchange(robot)):
            api.put_topic_permissions(
                vhost, site, exchange, write=owner_pattern(robot), read=owner_pattern(robot)
            )
        if keys := notified.get(inbox_queue(robot)):
            api.unbind_keys(vhost, NOTIFY_EXCHANGE, inbox_queue(robot), keys)
    for robot, kind in (returning or {}).items():
        for key in inbox_bindings(robot, kind, operator=False):
            api.bind(vhost, NOTIFY_EXCHANGE, inbox_queue(robot), key)
