"""Broker accounts: one per user, robot and service, each confined to its own name prefix.

The broker enforces the confinement: permissions allow configure, write and read only on
resources matching ``^<name>\\.``, topic permissions allow only routing keys starting with the
name, and every message a robot publishes carries ``user_id`` = its account, which RabbitMQ
checks against the connection's login.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote, unquote, urlsplit, urlunsplit

import pika
import pika.exceptions

from fleetbus.broker.account_roles import ROLE_TAGS, Role
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.shards import assign_shard, unassign_shard
from fleetbus.broker.topology import account_topology, core_topology, declare_with_url, inbox_bindings
from fleetbus.private_files import private_dir
from fleetbus.publishers.addresses import address_count, map_addresses
from fleetbus.publishers.tls import pika_parameter_list
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.routing import (
    NOTIFY_EXCHANGE,
    RECORDER_QUEUE,
    SERVICE_PREFIX,
    RobotKind,
    beacon_exchange,
    commands_exchange,
    events_exchange,
    inbox_queue,
    owner_pattern,
    requests_exchange,
    stream_queue,
)

SERVICE_USER = SERVICE_PREFIX
RECORDER_USER = f"{SERVICE_PREFIX}-recorder"

#: Topic permissions' pattern: routing keys that start with the account's own name (RabbitMQ
#: expands ``{username}``).
TOPIC_PATTERN = owner_pattern("{username}")

__all__ = ["ROLE_TAGS", "SERVICE_USER", "Account", "AccountExists", "Role"]


class AccountExists(RuntimeError):
    pass


@dataclass(frozen=True)
class Account:
    name: str
    role: Role
    amqp_url: str


def vhost_of(amqp_url: str) -> str:
    path = urlsplit(amqp_url).path
    return unquote(path[1:]) if len(path) > 1 else "/"


def url_for(amqp_url: str, username: str, password: str | None) -> str:
    """The same broker (every address of a cluster's URL) and virtual host as ``amqp_url``, logged
    in as another account (``password`` None: one that logs in with a client certificate)."""
    if address_count(amqp_url) > 1:
        return map_addresses(amqp_url, lambda single: url_for(single, username, password))
    parts = urlsplit(amqp_url)
    host = parts.hostname or "localhost"
    netloc = quote(username, safe="")
    if password is not None:
        netloc += f":{quote(password, safe='')}"
    netloc += f"@{host}"
    if parts.port:
        netloc += f":{parts.port}"
    return urlunsplit((parts.scheme, netloc, parts.path, parts.query, ""))


def as_public(amqp_url: str, public_url: str | None) -> str:
    """``amqp_url``'s login and virtual host at the broker's public address (``public_url``: its
    scheme, host, port and query, e.g. ``amqps://broker.example:5671/?cacertfile=...``): the URL a
    robot or a user is handed. Without a public address, ``amqp_url`` itself."""
    if not public_url:
        return amqp_url
    parts, public = urlsplit(amqp_url), urlsplit(public_url)
    host = public.hostname or "localhost"
    if ":" in host:
        host = f"[{host}]"
    netloc = f"{parts.netloc.rpartition('@')[0]}@{host}" if "@" in parts.netloc else host
    if public.port:
        netloc += f":{public.port}"
    return urlunsplit((public.scheme, netloc, parts.path or "/", public.query, ""))


def with_vhost(amqp_url: str, vhost: str) -> str:
    """The same login on another virtual host."""
    parts = urlsplit(amqp_url)
    return urlunsplit((parts.scheme, parts.netloc, "/" + quote(vhost, safe=""), parts.query, ""))


def fresh_vhost(api: ManagementAPI, admin_url: str, vhost: str) -> str:
    """Create ``vhost`` empty (deleting any old one), let the administrator in; return its URL."""
    api.delete_vhost(vhost)
    api.put_vhost(vhost)
    admin = unquote(urlsplit(admin_url).username or "")
    api.put_permissions(vhost, admin, ".*", ".*", ".*")
    return with_vhost(admin_url, vhost)


def confined_permissions(name: str, *, replies: bool = False) -> tuple[str, str, str]:
    """(configure, write, read) of an account confined to its prefix; ``replies`` also lets it
    answer requests by direct reply-to."""
    pattern = owner_pattern(name)
    write = f"{pattern}|^amq\\.default$" if replies else pattern
    return pattern, write, pattern


def keyed_exchanges(name: str, role: Role) -> list[str]:
    """The exchanges on which the account may use only routing keys that start with its name."""
    keyed = [events_exchange(name), requests_exchange(name)]
    if role is Role.ROBOT:
        keyed.append(beacon_exchange(name))
    return keyed


def _grant(api: ManagementAPI, vhost: str, name: str, *, replies: bool = False) -> None:
    configure, write, read = confined_permissions(name, replies=replies)
    api.put_permissions(vhost, name, configure=configure, write=write, read=read)


async def provision_account(
    admin_url: str,
    api: ManagementAPI,
    name: str,
    role: Role,
    kind: RobotKind | None = None,
    *,
    rotate: bool = False,
    shards: int = 1,
    cluster: bool = False,
    password_login: bool = True,
) -> Account:
    """Create (or with ``rotate``, re-key) an account with its exchange, inbox and permissions;
    a robot is bound to one of the ``shards`` ingest shards (``FLEETBUS_INGEST_SHARDS``). Without
    ``password_login`` the account has no password at all: it logs in with a client certificate
    (EXTERNAL) only, and its URL carries no password."""
    validate_name(name)
    if role is not Role.ROBOT and kind is not None:
        raise ValueError("--kind applies to robots only")
    if api.get_user(name) is not None and not rotate:
        what = "a new password" if password_login else "a new certificate and no password"
        raise AccountExists(f"user {name!r} exists; use --rotate to give it {what}")
    password: str | None = None
    if password_login:
        password = secrets.token_urlsafe(24)
        api.put_user(name, password, ROLE_TAGS[role])
    else:
        api.put_user_without_password(name, ROLE_TAGS[role])
    await configure_account(admin_url, api, name, role, kind, shards=shards, cluster=cluster)
    return Account(name, role, url_for(admin_url, name, password))


async def configure_account(
    admin_url: str,
    api: ManagementAPI,
    name: str,
    role: Role,
    kind: RobotKind | None = None,
    *,
    shards: int = 1,
    cluster: bool = False,
) -> None:
    """Grant an existing account its confined permissions and declare what it owns (idempotent);
    a robot keeps its ingest shard, or gets the least loaded of ``shards``. ``cluster``: the
    broker is a cluster (``FLEETBUS_CLUSTER``), its queues quorum queues."""
    validate_name(name)
    vhost = vhost_of(admin_url)
    api.put_user_tags(name, ROLE_TAGS[role])
    _grant(api, vhost, name)
    for exchange in keyed_exchanges(name, role):
        api.put_topic_permissions(vhost, name, exchange, write=TOPIC_PATTERN, read=TOPIC_PATTERN)
    await declare_with_url(
        admin_url,
        [core_topology(shards, cluster=cluster), account_topology(name, role, kind=kind, cluster=cluster)],
    )
    if role is Role.ROBOT:
        assign_shard(api, vhost, name, shards)
    else:  # a robot given another role publishes no events of its own
        unassign_shard(api, vhost, name)


def drop_other_roles(api: ManagementAPI, vhost: str, name: str, role: Role, kind: RobotKind | None) -> None:
    """What an account's earlier role had and its role now has not: an operator's notifications
    (every one), stream (every beacon) and commands exchange, when it is one no longer. For a
    change of role only: a new account has nothing of another role's (and the broker's management
    API is not asked three more questions for each account made)."""
    wanted = set(inbox_bindings(name, kind, role is Role.OPERATOR))
    inbox = inbox_queue(name)
    stale = [
        b["routing_key"]
        for b in api.exchange_bindings(vhost, NOTIFY_EXCHANGE)
        if b["destination"] == inbox and b["destination_type"] == "queue" and b["routing_key"] not in wanted
    ]
    if stale:
        api.unbind_keys(vhost, NOTIFY_EXCHANGE, inbox, stale)
    if role is not Role.OPERATOR:
        api.delete_queue(vhost, stream_queue(name))
        api.delete_exchange(vhost, commands_exchange(name))


def revoke_account(admin_url: str, api: ManagementAPI, name: str) -> None:
    """Take every permission in the virtual host away: the account can no longer even connect; and
    what feeds it (its inbox's notifications, an operator's stream and commands exchange)."""
    validate_name(name)
    vhost = vhost_of(admin_url)
    api.delete_permissions(vhost, name)
    api.put_user_tags(name, "")
    drop_other_roles(api, vhost, name, Role.USER, None)


def _keyed_account(admin_url: str, api: ManagementAPI, credentials_dir: Path, name: str, role: Role) -> str:
    """A service account whose password lives in ``credentials_dir`` (mode 0600); its URL.

    The password is re-keyed when that file is missing, so a fresh data directory never needs
    the old secret. Processes starting at once (several workers) take turns: the first re-keys,
    the others read what it saved, so none is left holding a password that was just replaced.
    """
    with _exclusive(credentials_dir / f".{name}.lock"):
        password = kept_password(credentials_dir, name)
        if password is None or not can_login(url_for(admin_url, name, password)):
            password = secrets.token_urlsafe(24)
            api.put_user(name, password, ROLE_TAGS[role])
            save_secret(kept_password_file(credentials_dir, name), password)
    return url_for(admin_url, name, password)


def kept_password_file(credentials_dir: Path, name: str) -> Path:
    """Where ``fleetbus setup`` keeps a service account's password (mode 0600)."""
    return credentials_dir / f"{name}.password"


def kept_password(credentials_dir: Path, name: str) -> str | None:
    """The password ``fleetbus setup`` kept for a service account; None when there is none."""
    path = kept_password_file(credentials_dir, name)
    return path.read_text().strip() if path.exists() else None


@contextlib.contextmanager
def _exclusive(lock_file: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``lock_file`` (waited for), between processes of this machine."""
    private_dir(lock_file.parent)
    fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def ensure_service_account(admin_url: str, api: ManagementAPI, credentials_dir: Path) -> str:
    """The workers' own account (``fleetbus``, confined to ``fleetbus.*``); returns its URL."""
    url = _keyed_account(admin_url, api, credentials_dir, SERVICE_USER, Role.SERVICE)
    _grant(api, vhost_of(admin_url), SERVICE_USER, replies=True)
    return url


def ensure_recorder_account(admin_url: str, api: ManagementAPI, credentials_dir: Path) -> str:
    """The recorder's account: it may read its one queue and nothing else (it neither declares,
    binds nor publishes; the administrator declares its queue and bindings). Returns its URL."""
    url = _keyed_account(admin_url, api, credentials_dir, RECORDER_USER, Role.SERVICE)
    api.put_permissions(
        vhost_of(admin_url), RECORDER_USER, configure="^$", write="^$", read=f"^{re.escape(RECORDER_QUEUE)}$"
    )
    return url


def can_login(amqp_url: str) -> bool:
    """Whether the broker accepts this URL's credentials (it answers at all, or this raises)."""
    parameters = pika_parameter_list(amqp_url, connection_attempts=1, socket_timeout=5)
    try:
        pika.BlockingConnection(parameters).close()
    except (pika.exceptions.ProbableAuthenticationError, pika.exceptions.AuthenticationError):
        return False  # AuthenticationError: the broker does not offer the URL's mechanism
    except pika.exceptions.ProbableAccessDeniedError:
        return True  # the password is right; the permissions are granted next
    return True


def save_secret(path: Path, secret: str) -> None:
    private_dir(path.parent)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)  # a file that was there keeps its mode through O_CREAT: narrowed first
    with os.fdopen(fd, "w") as handle:
        handle.write(secret + "\n")


def save_secret_once(path: Path, secret: str) -> None:
    """Write ``path`` (mode 0600) unless it exists; never a half-written file. Processes racing
    to make it all keep the first: each writes a file of its own whole, then links it into
    place, which fails for all but one."""
    private_dir(path.parent)
    draft = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
    save_secret(draft, secret)
    try:
        os.link(draft, path)
    except FileExistsError:
        pass  # another process was first: its secret is the one
    finally:
        draft.unlink()


def delete_account(admin_url: str, api: ManagementAPI, name: str) -> None:
    """Remove the account and its ingest shard binding; its exchange and inbox stay."""
    validate_name(name)
    api.delete_user(name)
    unassign_shard(api, vhost_of(admin_url), name)
