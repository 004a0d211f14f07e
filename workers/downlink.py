"""On a site: apply what central sent over the downlink (``fleetbus.downlink``) to this broker.

Each robot account is made here with central's password hash (so the robot's central password
works at its site), granted and given its topology as ``fleetbus users add`` would, entered in the
team with its kind, and its events bound into the uplink (forwarded to central). A message is
acked once applied; applying one again changes nothing. Run as the site's administrator
(``fleetbus site apply``): the workers' account may not make users."""

from __future__ import annotations

import asyncio
import logging
import threading

import pika
from pydantic import ValidationError

from fleetbus.broker.accounts import Role, configure_account, vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.sites import forward_robot
from fleetbus.broker.tls import pika_parameters
from fleetbus.schemas.routing import DOWNLINK_QUEUE
from fleetbus.schemas.site_changes import RobotAccount
from fleetbus.settings import Settings
from fleetbus.workers.store import run_with_repositories

log = logging.getLogger("fleetbus.sites")


def apply_account(settings: Settings, admin_url: str, api: ManagementAPI, account: RobotAccount) -> None:
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


def apply_downlink(
    settings: Settings,
    admin_url: str,
    api: ManagementAPI,
    *,
    idle_s: float | None = None,
    stop: threading.Event | None = None,
) -> int:
    """Apply the downlink's messages until ``stop`` is set, or (``idle_s``) until none came for that
    long; return how many were applied. One that does not parse is logged and dropped (acked)."""
    applied = 0
    connection = pika.BlockingConnection(pika_parameters(admin_url))
    try:
        channel = connection.channel()
        channel.basic_qos(prefetch_count=16)
        for method, _, body in channel.consume(DOWNLINK_QUEUE, inactivity_timeout=idle_s or 1.0):
            if method is None:
                if idle_s is not None or (stop is not None and stop.is_set()):
                    break
                continue
            try:
                account = RobotAccount.model_validate_json(body)
            except ValidationError as error:
                log.error("a downlink message that is not an account change, dropped: %s", error)
            else:
                apply_account(settings, admin_url, api, account)
                applied += 1
            channel.basic_ack(method.delivery_tag)
            if stop is not None and stop.is_set():
                break
        channel.cancel()
    finally:
        connection.close()
    return applied
