"""On a site: apply what central sent over the downlink (``fleetbus.downlink``) to this broker.

Each robot account is made here with central's password hash (so the robot's central password
works at its site), granted and given its topology as ``fleetbus users add`` would, entered in the
team with its kind, and its events bound into the uplink (forwarded to central); a robot the site
no longer has loses its account here, its forwarding and its place in the team (the list of the
site's robots that ``fleetbus sites sync`` sends removes every copy central gave that it does not
name), unless it is in use at the site (mounted). A message about a robot is applied only if the
site applied no newer one about it (by the revision of central's list of the site's robots it
carries): one that waited while a newer change went ahead (a sync that read the list before an
``--add`` or ``--remove``) is skipped, logged. Each mission is written into the site's missions
as central has it, unless the site already has that version or a newer one. Each map is stored as
a new version of the site's maps (once per map event), so the site's map service hands it to the
site's robots; a large map's chunks are kept in the site's store until the change that names them
commits them. A message is acked once applied; applying one again changes nothing. A message that
is no change this version knows (or a map whose image is not what its checksum says, or the
removal of an account in use at the site) is moved, unchanged, to ``fleetbus.downlink.rejected``
with the reason (confirmed there before it leaves the downlink): ``fleetbus site status`` counts
it. Run as the site's administrator (``fleetbus site apply``): the workers' account may not make
users."""

from __future__ import annotations

import asyncio
import hashlib
import logging
import threading
import time
from collections.abc import Callable

import pika
from pika.adapters.blocking_connection import BlockingChannel
from pydantic import ValidationError

from fleetbus.broker.accounts import Role, configure_account, delete_account, vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import forward_robot, forwarded_robots, stop_forwarding
from fleetbus.broker.team_changes import HazardServiceNotTold
from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.bodies import MAP_CHUNK_BYTES
from fleetbus.schemas.pgm import check_pgm
from fleetbus.schemas.routing import DOWNLINK_QUEUE, DOWNLINK_REJECTED_QUEUE
from fleetbus.schemas.site_changes import (
    MapChange,
    MapChunk,
    MissionChange,
    RobotAccount,
    RobotAccountRemoved,
    RobotRoster,
    parse_site_change,
)
from fleetbus.settings import Settings
from fleetbus.workers.account_use import in_use
from fleetbus.workers.store import Repositories, run_with_repositories
from fleetbus.workers.store.missions import Mission
from fleetbus.workers.team import leave_team

log = logging.getLogger("fleetbus.sites")


def newest(settings: Settings, robot: str, revision: int | None, what: str) -> bool:
    """Whether central's word on ``robot`` (``what``: which), made from its list's ``revision``, is
    the newest the site has had about it (then kept as such). None: from a central that numbers no
    revisions (applied as before)."""
    if revision is None:
        return True
    if run_with_repositories(settings, lambda repos: repos.sites.note_revision(robot, revision)):
        return True
    log.info("%s of %s skipped: central's revision %d is older than one applied", what, robot, revision)
    return False


def apply_account(settings: Settings, admin_url: str, api: ManagementAPI, account: RobotAccount) -> None:
    if not newest(settings, account.name, account.revision, "account"):
        return
    api.put_user_hash(account.name, account.password_hash, account.hashing_algorithm)
    asyncio.run(
        configure_account(
            admin_url, api, account.name, Role.ROBOT, account.kind, shards=settings.ingest_shards
        )
    )
    kind = account.kind.value if account.kind else None
    run_with_repositories(settings, lambda repos: repos.hazards.register_robot(account.name, kind))
    forward_robot(api, vhost_of(admin_url), account.name)
    log.info("account %s (%s) applied from central", account.name, kind or "no kind")


class RemovalRefused(ValueError):
    """Central asked the site to remove a robot's account that is in use at the site."""


def remove_account(
    settings: Settings, admin_url: str, api: ManagementAPI, name: str, revision: int | None = None
) -> None:
    """Remove the site's copy of a robot's account (central removed the robot, or took it from
    this site): it no longer logs in here, its events are no longer forwarded, and it leaves the
    site's team (a warden's leaving is told to the site's hazard service). Its exchange and inbox
    stay, with whatever they hold. Removing one the site does not have changes nothing. Refused
    (:class:`RemovalRefused`, nothing changed) while the robot is in use at the site, as central
    refuses to remove one in use there. A robot of the site's own (not forwarded for central) is
    not central's to remove: left as it is. ``revision``: that of central's list the removal was
    made from (skipped when the site applied a newer message about the robot)."""
    if not newest(settings, name, revision, "removal"):
        return
    if name not in forwarded_robots(api, vhost_of(admin_url)):
        log.warning("central asked to remove %s, which is not a robot central gave this site: left", name)
        return
    if problem := run_with_repositories(settings, lambda repos: in_use(repos.channels, name)):
        raise RemovalRefused(f"the site keeps the account of {name}, which central removed: {problem}")
    stop_forwarding(api, vhost_of(admin_url), name)
    delete_account(admin_url, api, name)
    try:
        run_with_repositories(settings, lambda repos: leave_team(repos.hazards, admin_url, name, "central"))
    except HazardServiceNotTold as error:  # the team has changed: the gate learns it at its next start
        log.warning("account %s removed as central asked, but %s", name, error)
    log.info("account %s removed as central asked", name)


def apply_roster(settings: Settings, admin_url: str, api: ManagementAPI, roster: RobotRoster) -> list[str]:
    """Remove the site's copies of the accounts central gave it (the robots whose events it
    forwards) that are not on central's list of the site's robots; the robots removed. Those in
    use stay, and :class:`RemovalRefused` names them once the others are removed."""
    removed, refused = [], []
    for name in sorted(forwarded_robots(api, vhost_of(admin_url)) - set(roster.names)):
        if not newest(settings, name, roster.revision, "list without it"):
            continue  # added by a newer change than this list
        try:
            remove_account(settings, admin_url, api, name)
        except RemovalRefused as refusal:
            refused.append(str(refusal))
        else:
            removed.append(name)
    if refused:
        raise RemovalRefused("; ".join(refused))
    return removed


def apply_mission(settings: Settings, change: MissionChange) -> bool:
    """Write the mission into the site's store unless it has that version or a newer one."""
    mission = Mission(**change.model_dump(exclude={"change"}))
    written = run_with_repositories(settings, lambda repos: repos.missions.put_mission(mission))
    if written:
        log.info("mission %s (%s) applied from central", mission.mission_id, mission.state.value)
    return written


def apply_map_chunk(settings: Settings, chunk: MapChunk) -> None:
    """Keep a large map's chunk in the site's store until its map change arrives (idempotent)."""
    run_with_repositories(
        settings, lambda repos: repos.maps.stage_map_chunk(chunk.map_id, chunk.index, chunk.data)
    )


async def _image(repos: Repositories, change: MapChange) -> bytes:
    """The change's PGM: its own, or its chunks joined; ValueError when one is missing."""
    if not change.chunks:
        return change.pgm
    assert change.map_id is not None
    staged = await repos.maps.staged_map_chunks(change.map_id)
    missing = sorted(set(range(change.chunks)) - set(staged))
    if missing:
        raise ValueError(
            f"map of {change.robot_id} ({change.epoch}, {change.seq}): chunks {missing} never arrived"
        )
    return b"".join(staged[index] for index in range(change.chunks))


def apply_map(settings: Settings, change: MapChange) -> bool:
    """Store the map as the site's newest version unless its map event was stored already;
    ValueError when the image is not the PGM its checksum says, or a chunk of it is missing."""

    async def store(repos: Repositories) -> bool:
        if await repos.maps.committed_map(change.robot_id, change.epoch, change.seq) is not None:
            return False
        image = await _image(repos, change)
        if hashlib.sha256(image).hexdigest() != change.sha256:
            raise ValueError(
                f"map of {change.robot_id} ({change.epoch}, {change.seq}): SHA-256 does not match"
            )
        check_pgm(image)
        version = await repos.maps.commit_map(
            change.robot_id,
            change.epoch,
            change.seq,
            image,
            change.metadata,
            change.created_at,
            change.sha256,
            MAP_CHUNK_BYTES,
            change.map_id,
        )
        log.info("map of %s applied from central as version %d", change.robot_id, version.version)
        return True

    return run_with_repositories(settings, store)


def _reject(channel: BlockingChannel, properties: pika.BasicProperties, body: bytes, error: str) -> None:
    """Keep an unparsable message in the rejected queue (confirmed) before it leaves the downlink."""
    headers = dict(properties.headers or {})
    headers["x-fleetbus-rejected"] = error[:1000]
    properties.headers = headers
    channel.basic_publish("", DOWNLINK_REJECTED_QUEUE, body, properties, mandatory=True)


def apply_downlink(
    settings: Settings,
    admin_url: str,
    api: ManagementAPI,
    *,
    idle_s: float | None = None,
    stop: threading.Event | None = None,
    tick: Callable[[], object] | None = None,
    tick_every_s: float = 30.0,
) -> int:
    """Apply the downlink's messages until ``stop`` is set, or (``idle_s``) until none came for that
    long; return how many were applied. One that does not parse is moved to the rejected queue.
    ``tick`` (the site's report to central) is called at the start and every ``tick_every_s``."""
    applied = 0
    next_tick = time.monotonic()
    connection = pika.BlockingConnection(pika_parameters(admin_url))
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        channel.queue_declare(DOWNLINK_REJECTED_QUEUE, durable=True, arguments={"x-queue-type": "classic"})
        channel.basic_qos(prefetch_count=16)
        for method, properties, body in channel.consume(DOWNLINK_QUEUE, inactivity_timeout=idle_s or 1.0):
            if tick is not None and time.monotonic() >= next_tick:
                tick()
                next_tick = time.monotonic() + tick_every_s
            if method is None:
                if idle_s is not None or (stop is not None and stop.is_set()):
                    break
                continue
            try:
                change = parse_site_change(body)
                if isinstance(change, MapChunk):
                    apply_map_chunk(settings, change)
                elif isinstance(change, MapChange):
                    apply_map(settings, change)
                elif isinstance(change, RobotAccountRemoved):
                    remove_account(settings, admin_url, api, change.name, change.revision)
                elif isinstance(change, RobotRoster):
                    apply_roster(settings, admin_url, api, change)
            except (ValidationError, ValueError) as error:
                log.error(
                    "a downlink message that cannot be applied, moved to %s: %s",
                    DOWNLINK_REJECTED_QUEUE,
                    error,
                )
                _reject(channel, properties, body, str(error))
            else:
                if isinstance(change, RobotAccount):
                    apply_account(settings, admin_url, api, change)
                elif isinstance(change, MissionChange):
                    apply_mission(settings, change)
                applied += 1
            channel.basic_ack(method.delivery_tag)
            if stop is not None and stop.is_set():
                break
        channel.cancel()
    finally:
        connection.close()
    return applied
