"""Many robots' accounts at once: one definitions import instead of a dozen calls per robot.

``fleetbus users add`` makes one account with about a dozen management API calls (the user, its
permissions, three topic permissions, its exchanges, inbox and bindings declared with the whole
core topology again, and a read of every shard binding to pick the least loaded shard), and the
command's own start costs about a second: 1,000 robots took 17 minutes. Here the accounts of a
whole batch, with everything they own and their shard bindings, go to the broker as one document
(RabbitMQ's definitions import, ``POST /api/definitions``), after one read of the shard map.

The passwords are made here and hashed as RabbitMQ hashes them (``rabbit_password_hashing_sha256``:
a 4-byte salt, SHA-256 of the salt and the password, base64), so the document carries no password.
"""

from __future__ import annotations

import base64
import hashlib
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from fleetbus.broker.account_roles import ROLE_TAGS, Role
from fleetbus.broker.accounts import TOPIC_PATTERN, Account, url_for, vhost_of
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.shards import read_shard_map
from fleetbus.broker.topology import Topology, account_topology, core_topology, declare_with_url
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import (
    SHARD_EXCHANGE,
    RobotKind,
    beacon_exchange,
    events_exchange,
    ingest_shard_queue,
    owner_pattern,
    requests_exchange,
    shard_binding_keys,
)

HASHING = "rabbit_password_hashing_sha256"


@dataclass(frozen=True)
class NewRobot:
    name: str
    kind: RobotKind | None = None


class RobotsExist(Exception):
    """Some of the accounts exist already (and no new passwords were asked for)."""


def password_hash(password: str, salt: bytes | None = None) -> str:
    """RabbitMQ's ``rabbit_password_hashing_sha256`` of ``password``."""
    salt = secrets.token_bytes(4) if salt is None else salt
    return base64.b64encode(salt + hashlib.sha256(salt + password.encode()).digest()).decode()


def _topology_definitions(vhost: str, topology: Topology) -> dict[str, list[dict[str, Any]]]:
    return {
        "exchanges": [
            {
                "name": spec.name,
                "vhost": vhost,
                "type": str(getattr(spec.type, "value", spec.type)),
                "durable": True,
                "auto_delete": False,
                "internal": False,
                "arguments": spec.arguments,
            }
            for spec in topology.exchanges
        ],
        "queues": [
            {
                "name": spec.name,
                "vhost": vhost,
                "durable": True,
                "auto_delete": False,
                "arguments": spec.arguments,
            }
            for spec in topology.queues
        ],
        "bindings": [
            {
                "source": spec.source,
                "vhost": vhost,
                "destination": spec.destination,
                "destination_type": "exchange" if spec.to_exchange else "queue",
                "routing_key": spec.routing_key,
                "arguments": spec.arguments,
            }
            for spec in topology.bindings
        ],
    }


def robots_definitions(
    vhost: str,
    robots: Sequence[NewRobot],
    hashes: dict[str, str],
    shard_of: dict[str, int],
    cluster: bool = False,
) -> dict[str, Any]:
    """The definitions document for ``robots``: each account as ``fleetbus users add`` makes it
    (:func:`~fleetbus.broker.accounts.configure_account`), bound to its shard of ``shard_of``."""
    document: dict[str, list[dict[str, Any]]] = {
        "users": [],
        "permissions": [],
        "topic_permissions": [],
        "exchanges": [],
        "queues": [],
        "bindings": [],
    }
    for robot in robots:
        name = robot.name
        pattern = owner_pattern(name)
        user = {"name": name, "password_hash": hashes[name], "hashing_algorithm": HASHING}
        document["users"].append({**user, "tags": ROLE_TAGS[Role.ROBOT]})
        document["permissions"].append(
            {"user": name, "vhost": vhost, "configure": pattern, "write": pattern, "read": pattern}
        )
        for exchange in (events_exchange(name), requests_exchange(name), beacon_exchange(name)):
            where = {"user": name, "vhost": vhost, "exchange": exchange}
            document["topic_permissions"].append({**where, "write": TOPIC_PATTERN, "read": TOPIC_PATTERN})
        for part, items in _topology_definitions(
            vhost, account_topology(name, Role.ROBOT, kind=robot.kind, cluster=cluster)
        ).items():
            document[part] += items
        document["bindings"] += [
            {
                "source": SHARD_EXCHANGE,
                "vhost": vhost,
                "destination": ingest_shard_queue(shard_of[name]),
                "destination_type": "queue",
                "routing_key": key,
                "arguments": {},
            }
            for key in shard_binding_keys(name)
        ]
    return document


async def provision_robots(
    admin_url: str,
    api: ManagementAPI,
    robots: Sequence[NewRobot],
    *,
    rotate: bool = False,
    shards: int = 1,
    cluster: bool = False,
    batch: int = 500,
) -> list[Account]:
    """Make (or with ``rotate``, re-key) the accounts of ``robots``, each with what it owns and its
    shard (the least loaded, robot by robot), ``batch`` accounts per definitions import. Raises
    :class:`RobotsExist`, making none, when some exist and ``rotate`` is not given."""
    for robot in robots:
        validate_name(robot.name)
    names = [robot.name for robot in robots]
    if len(set(names)) != len(names):
        twice = sorted({name for name in names if names.count(name) > 1})
        raise ValueError(f"named twice: {', '.join(twice)}")
    existing = {user["name"] for user in api.list_users()} & set(names)
    if existing and not rotate:
        raise RobotsExist(
            f"{len(existing)} exist already ({', '.join(sorted(existing)[:5])}"
            f"{', ...' if len(existing) > 5 else ''}); use --rotate to give them new passwords"
        )
    vhost = vhost_of(admin_url)
    await declare_with_url(admin_url, [core_topology(shards, cluster=cluster)])
    shard_map = read_shard_map(api, vhost, shards)
    load = shard_map.load()
    shard_of: dict[str, int] = {}
    for name in names:
        bound = shard_map.bindings.get(name)
        if bound:
            shard_of[name] = bound[0]  # a robot keeps its shard
            continue
        shard_of[name] = min(range(shards), key=lambda shard: (load[shard], shard))
        load[shard_of[name]] += 1
    passwords = {name: secrets.token_urlsafe(24) for name in names}
    for start in range(0, len(robots), batch):
        part = robots[start : start + batch]
        hashes = {robot.name: password_hash(passwords[robot.name]) for robot in part}
        api.import_definitions(robots_definitions(vhost, part, hashes, shard_of, cluster))
    return [Account(name, Role.ROBOT, url_for(admin_url, name, passwords[name])) for name in names]
