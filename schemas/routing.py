"""The naming and routing-key convention of the bus, written down once.

Robots and users own every resource that starts with their name::

    <robot>.events      topic exchange the robot publishes to (write permission ``^<robot>\\.``)
    <robot>.inbox       durable queue of the notifications the robot subscribed to
    <robot>.requests    topic exchange of the robot's service requests, keys ``<robot>.<method>``

    <robot>.beacon      topic exchange of the robot's beacons, keys ``<robot>.beacon``: topic
                        permissions make the broker refuse any other key, so a robot's beacons
                        reach its own lane only. It feeds fleetbus.beacon.check, which passes
                        only messages with the headers ``type: beacon`` and ``codename``
    <robot>.commands    queue of the commands of the operator who mounted the robot
    <operator>.commands topic exchange an operator sends commands to, keys ``<robot>.<command>``;
                        mounting binds it to the robot's commands queue
    <operator>.stream   stream queue an operator follows (``fleetbus tail``): every beacon, and
                        the events of the robots it mounted

Event routing keys are ``<robot>.<type>`` (for example ``explorer1.hazard``); topic permissions
make the broker refuse any key that does not start with the publisher's own name.

The service owns everything that starts with ``fleetbus.``::

    fleetbus.ingest         topic exchange; every ``<robot>.events`` is bound into it with ``#``
    fleetbus.ingest.shards  topic exchange fed by fleetbus.ingest with ``#``. Hazards and
                            localisations (``*.hazard``, ``*.localisation``) are bound to the express
                            queue; each robot's other types (``<robot>.status``, ``<robot>.map``...)
                            to one ingest shard (made when its account is provisioned)
    fleetbus.ingest.express classic queue of the express lane (single active consumer), read by the
                            worker that holds shard 0: a hazard never waits behind the bulk
    fleetbus.ingest.unassigned  fanout exchange, the alternate exchange of fleetbus.ingest.shards:
                            whatever no robot binding matches goes to shard 0
    fleetbus.ingest.events  quorum queue of ingest shard 0 (single active consumer); shards 1, 2...
                            are fleetbus.ingest.events.1, .2... (``FLEETBUS_INGEST_SHARDS``)
    fleetbus.notify         topic exchange of notifications, keys ``notify.<topic>``
    fleetbus.rpc            topic exchange of service requests; every ``<robot>.requests`` is bound into it
    fleetbus.rpc.requests   queue the service answers from (replies go by direct reply-to)
    fleetbus.beacon.check   headers exchange every <robot>.beacon is bound into with ``#``: a message with
                            the headers ``type: beacon`` and ``codename`` goes on to fleetbus.beacon;
                            the rest go to its alternate exchange, fleetbus.beacon.discard, and are counted
    fleetbus.beacon         topic exchange of every robot's accepted beacons, bound into the ingest
                            and into every operator's stream
    fleetbus.beacon.discard fanout exchange, the alternate exchange of fleetbus.beacon.check
    fleetbus.beacon.discarded  queue of discarded beacon messages; the workers count them
    fleetbus.dlx            dead-letter exchange (fanout)
    fleetbus.dead-letters   classic durable queue of rejected messages, with their reasons
    fleetbus.recorder       classic durable queue of a copy of everything on ingest, notify, rpc, dlx and
                            the beacon discards, read only by the recorder's account ``fleetbus-recorder``
    fleetbus.recorder.dlx   fanout exchange into fleetbus.dead-letters, the recorder queue's dead-letter
                            exchange (a policy ``fleetbus setup`` sets): what the recorder cannot store

A site (docs/guides/sites.md) adds, on its own broker::

    fleetbus.uplink         classic durable queue bound to fleetbus.ingest with ``#``: everything the site
                            accepted, until the shovel ``fleetbus-uplink`` has it confirmed by central
    fleetbus.downlink       classic durable queue the shovel ``fleetbus-downlink`` fills from central

and central, for each site ``<site>`` (an account of its own, tagged ``impersonator``)::

    fleetbus.sites          topic exchange of what central sends its sites, keys ``<site>.<kind>``
    <site>.downlink         queue of one site's share of it, bound with ``<site>.#``
"""

from __future__ import annotations

from enum import Enum

SERVICE_PREFIX = "fleetbus"
INGEST_EXCHANGE = "fleetbus.ingest"
INGEST_QUEUE = "fleetbus.ingest.events"
EXPRESS_QUEUE = "fleetbus.ingest.express"
SHARD_EXCHANGE = "fleetbus.ingest.shards"
UNASSIGNED_EXCHANGE = "fleetbus.ingest.unassigned"
NOTIFY_EXCHANGE = "fleetbus.notify"
RPC_EXCHANGE = "fleetbus.rpc"
RPC_QUEUE = "fleetbus.rpc.requests"
BEACON_EXCHANGE = "fleetbus.beacon"
BEACON_CHECK_EXCHANGE = "fleetbus.beacon.check"
BEACON_DISCARD_EXCHANGE = "fleetbus.beacon.discard"
BEACON_DISCARD_QUEUE = "fleetbus.beacon.discarded"
#: The headers a beacon message must carry (RabbitMQ matches a binding header without a value,
#: ``None`` here, on the header's presence alone).
BEACON_TYPE_HEADER = "type"
BEACON_TYPE = "beacon"
BEACON_CODENAME_HEADER = "codename"
BEACON_MATCH = {"x-match": "all", BEACON_TYPE_HEADER: BEACON_TYPE, BEACON_CODENAME_HEADER: None}
DEAD_LETTER_EXCHANGE = "fleetbus.dlx"
DEAD_LETTER_QUEUE = "fleetbus.dead-letters"
#: The dead-letter exchange of the queues whose messages also expire (service requests, commands):
#: it passes on to fleetbus.dlx only what a delivery limit removed, and drops what expired.
POISON_EXCHANGE = "fleetbus.poison"
RECORDER_QUEUE = "fleetbus.recorder"
#: The recorder queue's dead-letter exchange (fanout, into fleetbus.dead-letters): not fleetbus.dlx,
#: which the recorder records, so that a message the recorder cannot store never comes back to it.
RECORDER_DEAD_LETTER_EXCHANGE = "fleetbus.recorder.dlx"
#: Where the broker dead-letters what a full queue drops (the inboxes, the dead letters, the
#: recorder's backlog), so that the workers can count it.
OVERFLOW_EXCHANGE = "fleetbus.overflow"
OVERFLOW_QUEUE = "fleetbus.overflow.dropped"
#: Every exchange the service's traffic passes (robots' events, notifications, requests, dead
#: letters): the recorder's queue is bound to each with ``#``.
RECORDED_EXCHANGES = (
    INGEST_EXCHANGE,
    NOTIFY_EXCHANGE,
    RPC_EXCHANGE,
    DEAD_LETTER_EXCHANGE,
    BEACON_DISCARD_EXCHANGE,
)


UPLINK_QUEUE = "fleetbus.uplink"
UPLINK_SHOVEL = "fleetbus-uplink"
DOWNLINK_QUEUE = "fleetbus.downlink"
DOWNLINK_SHOVEL = "fleetbus-downlink"
DOWNLINK_MAPS_SHOVEL = "fleetbus-downlink-maps"
#: On a site: downlink messages ``fleetbus site apply`` could not parse, kept for a look.
DOWNLINK_REJECTED_QUEUE = "fleetbus.downlink.rejected"
SITES_EXCHANGE = "fleetbus.sites"
#: At central: every site's reports about itself (from its ``<site>.status`` exchange).
SITE_REPORTS_QUEUE = "fleetbus.site-reports"
#: On a site: its hazards' states on their way to central (the shovel ``fleetbus-hazard-uplink``
#: moves them to the site's ``<site>.hazards`` there).
HAZARD_UPLINK_QUEUE = "fleetbus.hazard-uplink"
HAZARD_UPLINK_SHOVEL = "fleetbus-hazard-uplink"
#: At central: every site's hazard states (from its ``<site>.hazards`` exchange), for the worker.
SITE_HAZARDS_QUEUE = "fleetbus.site-hazards"
#: The header the shovel adds to what it forwards (``dest-add-forward-headers``).
SHOVELLED_HEADER = "x-shovelled"


def site_downlink_queue(site: str) -> str:
    """Central's queue of what one site is sent (its robots' accounts, missions, maps)."""
    return f"{site}.downlink"


def site_maps_queue(site: str) -> str:
    """Central's queue of the maps one site is sent: apart, so a large map never holds a mission back."""
    return f"{site}.downlink.maps"


def site_status_exchange(site: str) -> str:
    """At central: where ``site`` publishes its reports (its account may write ``<site>.*``)."""
    return f"{site}.status"


def site_hazards_exchange(site: str) -> str:
    """At central: where ``site``'s hazard states arrive (its account may write ``<site>.*``)."""
    return f"{site}.hazards"


def site_of_hazards_exchange(exchange: str) -> str | None:
    """The site whose hazards exchange ``exchange`` is; None when it is none."""
    return _site_of(exchange, "hazards")


def site_of_status_exchange(exchange: str) -> str | None:
    """The site whose status exchange (its reports) ``exchange`` is; None when it is none."""
    return _site_of(exchange, "status")


def _site_of(exchange: str, kind: str) -> str | None:
    site, dot, rest = exchange.partition(".")
    return site if dot and rest == kind and site else None


def site_downlink_key(site: str, kind: str) -> str:
    return f"{site}.{kind}"


class EventType(str, Enum):
    HAZARD = "hazard"
    MAP = "map"
    MAP_CHUNK = "map_chunk"
    STATUS = "status"
    LOCALISATION = "localisation"
    BEACON = "beacon"
    BEHAVIOUR = "behaviour"
    ROS = "ros"
    ROS_CHUNK = "ros_chunk"
    MEASUREMENT = "measurement"


#: The express lane's types: the hazards the wardens wait for, and the localisations that open their
#: gate. They skip the shards, so none of them waits behind a robot's telemetry, maps or resync.
EXPRESS_TYPES = (EventType.HAZARD, EventType.LOCALISATION)
#: The types each robot's shard binding keys name: all but the express lane's.
SHARD_TYPES = tuple(t for t in EventType if t not in EXPRESS_TYPES)


class Topic(str, Enum):
    """What a notification is about; the routing key is ``notify.<topic>``."""

    HAZARD = "hazard"
    MAP = "map"
    BATTERY = "battery"


class RobotKind(str, Enum):
    EXPLORER = "explorer"
    WARDEN = "warden"
    GUIDE = "guide"


#: Notification topics each kind of robot subscribes to; operators get every topic.
SUBSCRIPTIONS: dict[RobotKind, tuple[Topic, ...]] = {
    RobotKind.EXPLORER: (),
    RobotKind.WARDEN: (Topic.HAZARD, Topic.MAP),
    RobotKind.GUIDE: (Topic.MAP,),
}
#: Topics the service delivers to each subscriber's inbox by name (the default exchange), not
#: through a binding: hazard announcements go to the wardens in service only, and the broker
#: returns a copy no inbox took, so the service knows a warden got it. Their copy on
#: ``fleetbus.notify`` (for operators and the recorder) names the wardens in ``ANNOUNCED_TO_HEADER``.
DELIVERED_BY_NAME = (Topic.HAZARD,)
ALL_TOPICS_BINDING = "notify.#"


def events_exchange(owner: str) -> str:
    return f"{owner}.events"


def requests_exchange(owner: str) -> str:
    return f"{owner}.requests"


def request_routing_key(robot: str, method: str) -> str:
    return f"{robot}.{method}"


def inbox_queue(owner: str) -> str:
    return f"{owner}.inbox"


def beacon_exchange(owner: str) -> str:
    return f"{owner}.beacon"


def commands_queue(robot: str) -> str:
    return f"{robot}.commands"


def commands_exchange(operator: str) -> str:
    return f"{operator}.commands"


def command_routing_key(robot: str, command: str) -> str:
    return f"{robot}.{command}"


def stream_queue(owner: str) -> str:
    return f"{owner}.stream"


def beacon_headers(codename: str) -> dict[str, str]:
    """The headers without which the broker discards a beacon message."""
    return {BEACON_TYPE_HEADER: BEACON_TYPE, BEACON_CODENAME_HEADER: codename}


def publish_exchange(robot: str, event_type: EventType | str) -> str:
    """Where a robot publishes this type: beacons to its beacon exchange, the rest to its events."""
    if EventType(event_type) is EventType.BEACON:
        return beacon_exchange(robot)
    return events_exchange(robot)


def event_routing_key(robot: str, event_type: EventType | str) -> str:
    return f"{robot}.{EventType(event_type).value}"


def split_event_routing_key(routing_key: str) -> tuple[str, str]:
    """Return ``(robot, type)`` of an event routing key; the type is not checked here."""
    robot, sep, type_name = routing_key.partition(".")
    if not sep or not robot or not type_name:
        raise ValueError(f"routing key {routing_key!r} is not of the form <robot>.<type>")
    return robot, type_name


def ingest_shard_queue(shard: int) -> str:
    """The queue of ingest shard ``shard``; shard 0 keeps the name of the single ingest queue."""
    if shard < 0:
        raise ValueError(f"shard numbers start at 0, not {shard}")
    return INGEST_QUEUE if shard == 0 else f"{INGEST_QUEUE}.{shard}"


def shard_of_queue(queue: str) -> int | None:
    """The shard an ingest queue serves, or None for any other queue."""
    if queue == INGEST_QUEUE:
        return 0
    prefix, _, number = queue.rpartition(".")
    if prefix == INGEST_QUEUE and number.isdigit() and number == str(int(number)) and int(number) > 0:
        return int(number)
    return None


def express_binding_key(event_type: EventType | str) -> str:
    """The key that takes every robot's events of ``event_type`` into the express lane."""
    return f"*.{EventType(event_type).value}"


def shard_binding_keys(robot: str) -> tuple[str, ...]:
    """The keys that bind ``robot``'s events of every type but the express lane's to its shard.

    One key per type rather than ``<robot>.#``, so that the split into the express lane costs no
    exchange hop of its own: the shard exchange routes hazards to the express queue and the rest
    to the robots' shards in one lookup.
    """
    return tuple(event_routing_key(robot, t) for t in SHARD_TYPES)


def notification_routing_key(topic: Topic | str) -> str:
    return f"notify.{Topic(topic).value}"


def owner_pattern(owner: str) -> str:
    """Regular expression of the resources (and routing keys) ``owner`` may touch."""
    return f"^{owner}\\."


#: On a hazard announcement's copy on ``fleetbus.notify``: the wardens whose inboxes took it.
ANNOUNCED_TO_HEADER = "x-fleetbus-announced-to"
