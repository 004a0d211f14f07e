"""A private RabbitMQ node that lives entirely in one folder (``.fleetbus/broker/`` by default).

Everything the node touches is inside ``base_dir``: its database (mnesia), logs, Erlang cookie
(``HOME=base_dir``), pid file, ``rabbitmq.conf``, ``advanced.config`` (the AMQPS listener's TLS
options), ``enabled_plugins`` and a ``rabbitmq-env.conf`` that shadows the system one. It binds to
127.0.0.1 only, on ports picked once and kept in ``node.json``, and its node name is derived from
the folder, so several checkouts (or a test's temporary folder) each get their own node next to
each other and next to a system RabbitMQ.

There is no ``guest`` account: the first boot creates ``fleetbus-admin`` with a random password
kept in ``admin.json`` (mode 0600).

All of the node's environment is built by :meth:`LocalNode.env`; the server and every CLI call
(:meth:`LocalNode.rabbitmqctl`) use it, which is what makes them find each other. They run from
the RabbitMQ installation :meth:`LocalNode.installation` names (:mod:`fleetbus_dev.rabbitmq`: the
host's package, or Debian 13's in a root of its own).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import random
import re
import secrets
import signal
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TypeVar
from urllib.parse import quote

import psutil

from fleetbus.broker.certificates import TlsFiles, make_certificates
from fleetbus.broker.probe import (
    amqp_login,
    management_answers,
    write_private_file,
)
from fleetbus.broker.retry import Backoff, GaveUp, retrying
from fleetbus.broker.revocation import ensure_crl
from fleetbus.broker.tls_profile import MANAGEMENT, erlang_terms, rabbitmq_conf
from fleetbus.private_files import OWNER_ONLY, private_dir, private_file
from fleetbus.processes import pid_alive
from fleetbus_dev.rabbitmq import HOST as HOST_ROOT
from fleetbus_dev.rabbitmq import Installation, InstallationError, default_installation, version_key

ADMIN_USER = "fleetbus-admin"
HOST = "127.0.0.1"
PORT_NAMES = ("amqp", "management", "dist", "epmd", "stream", "amqps", "management_tls")
#: The ports a node made by an older version lacks: chosen at its next start, listened on once it
#: starts again (a running node keeps the configuration it started with).
TLS_PORT_NAMES = ("amqps", "management_tls")
#: Ports no client is given: Erlang's distribution (found through epmd) and the stream listener
#: (fleetbus does not use streams). A restart moves them when another program took them meanwhile.
UNPUBLISHED_PORTS = ("dist", "stream")
#: How many times a new node starts on new ports when another process took one of its ports
#: between their choice and the node's listen.
PORT_RACE_ATTEMPTS = 3
#: What a start that lost a port writes to its console log: a listener's bind error, or prelaunch's
#: refusal of a taken distribution port.
PORT_IN_USE_MARKS = ("eaddrinuse", "dist_port_already_used")
#: The shovel plugins carry a site's events to central and central's changes back (docs/guides/sites.md);
#: rabbitmq_auth_mechanism_ssl lets robots log in with a client certificate (EXTERNAL).
PLUGINS = (
    "rabbitmq_management",
    "rabbitmq_shovel",
    "rabbitmq_shovel_management",
    "rabbitmq_auth_mechanism_ssl",
)

#: Erlang run by ``rabbitmqctl eval``: trigger an election in every quorum queue whose Ra
#: server does not know a leader; print their names.
_LEADERLESS_QUORUM_QUEUES = """
Leaderless = [Q || Q <- rabbit_amqqueue:list(),
                   amqqueue:get_type(Q) =:= rabbit_quorum_queue,
                   case ra:members(amqqueue:get_pid(Q), 2000) of {ok, _, _} -> false; _ -> true end],
[ra:trigger_election(amqqueue:get_pid(Q)) || Q <- Leaderless],
io:format("~p~n", [[rabbit_misc:rs(amqqueue:get_name(Q)) || Q <- Leaderless]]).
"""
#: Robots may log in with a client certificate signed by the node's CA, as the account its common
#: name names (EXTERNAL); passwords keep working (PLAIN, AMQPLAIN). A certificate is only ever
#: verified, never required: ``fail_if_no_peer_cert = false``.
CERTIFICATE_LOGIN = """\
auth_mechanisms.1 = PLAIN
auth_mechanisms.2 = AMQPLAIN
auth_mechanisms.3 = EXTERNAL
ssl_cert_login_from = common_name
"""

log = logging.getLogger("fleetbus.broker")
T = TypeVar("T")


def ensure_certificates(tls: TlsFiles) -> None:
    """A private node's (or cluster's) server certificate, made (with a CA, unless one exists) when
    it is missing from the folder fleetbus makes them in; the operator's own files are never made:
    one of them missing is an error that names it."""
    if tls.server_ready():
        return
    ours = TlsFiles.in_folder(tls.ca_key.parent)
    if tls != ours:
        missing = [str(path) for path in (tls.ca, tls.cert, tls.key) if not path.exists()]
        raise LocalNodeError(f"the TLS files FLEETBUS_TLS_CA/_CERT/_KEY name are missing: {missing}")
    log.info("making the private node's certificates in %s", ours.ca.parent)
    make_certificates(ours)


class LocalNodeError(RuntimeError):
    """The private node could not be started, reached or stopped; the message says why."""


@dataclass(frozen=True)
class NodeInfo:
    running: bool
    pid: int | None
    node_name: str
    base_dir: Path
    amqp_url: str | None
    """Administrator URL, ``amqp://fleetbus-admin:<pw>@127.0.0.1:<port>/``; None before the first up."""
    management_url: str | None
    """``http://127.0.0.1:<port>/``; None before the first up."""
    ports: dict[str, int] = field(default_factory=dict)
    log_file: Path | None = None
    amqps_url: str | None = None
    """The administrator over TLS, ``amqps://fleetbus-admin:<pw>@127.0.0.1:<port>/?cacertfile=<ca>``."""
    public_url: str | None = None
    """What robots on this machine are given: ``amqps://127.0.0.1:<port>/?cacertfile=<ca>``."""
    management_tls_url: str | None = None
    """``https://127.0.0.1:<port>/``, its certificate signed by ``tls.ca``."""


# --------------------------------------------------------------------------- processes


def _comm(pid: int) -> str:
    try:
        return psutil.Process(pid).name()
    except psutil.Error:
        return ""


def _environ(pid: int) -> dict[str, str] | None:
    try:
        return psutil.Process(pid).environ()
    except psutil.Error:
        return None


def _is_escript(pid: int) -> bool:
    """A beam started through escript: one of RabbitMQ's CLI tools, not a server."""
    try:
        return any("escript" in part for part in psutil.Process(pid).cmdline())
    except psutil.Error:
        return False


def listening_addresses(pid: int) -> list[tuple[str, int]]:
    """The ``(address, port)`` pairs process ``pid`` listens on (TCP, IPv4 and IPv6)."""
    try:
        connections = psutil.Process(pid).net_connections(kind="tcp")
    except psutil.Error:
        return []
    return sorted((c.laddr.ip, c.laddr.port) for c in connections if c.status == psutil.CONN_LISTEN)


def pids_listening_on(port: int) -> list[int]:
    """Processes with a TCP socket listening on ``port`` (any address)."""
    return sorted(
        {
            c.pid
            for c in psutil.net_connections(kind="tcp")
            if c.pid and c.status == psutil.CONN_LISTEN and c.laddr.port == port
        }
    )


def _wait_until(condition: Callable[[], T], timeout: float, interval: float = 0.1) -> T | None:
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(interval)


class _LockBusy(Exception):
    """Another process holds the node's lock."""


def _lock_now(handle: IO[str]) -> None:
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        if error.errno in (errno.EAGAIN, errno.EACCES):
            raise _LockBusy(str(error)) from error
        raise


def _signal(pid: int, sig: signal.Signals) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, sig)


# --------------------------------------------------------------------------- ports and secrets


def _port_free(port: int) -> bool:
    """Whether a listener could bind ``127.0.0.1:port`` now (as Erlang does, with SO_REUSEADDR)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((HOST, port))
        except OSError:
            return False
    return True


def _ephemeral_range() -> tuple[int, int]:
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(low), int(high)
    except (OSError, ValueError):
        return 32768, 60999


def choose_free_ports(count: int) -> list[int]:
    """``count`` distinct free ports below the ephemeral range, so that no outgoing connection's
    source port takes one of them while the node is down."""
    low, high = _ephemeral_range()
    candidates = list(range(20000, low)) if low > 21000 else list(range(high + 1, 65000))
    random.SystemRandom().shuffle(candidates)
    chosen = [port for port in candidates[:500] if _port_free(port)][:count]
    if len(chosen) < count:
        raise LocalNodeError("could not find free TCP ports on 127.0.0.1 for the private RabbitMQ node")
    return chosen


def _erlang_string(path: Path) -> str:
    """``path`` as an Erlang string literal."""
    return '"' + str(path).replace("\\", "\\\\").replace('"', '\\"') + '"'


def _write_if_changed(path: Path, text: str) -> None:
    """``path`` holds ``text`` (its owner's only, as everything in the node's folder)."""
    if not path.exists() or path.read_text() != text:
        write_private_file(path, text)


def _tail(path: Path, lines: int = 30) -> str:
    try:
        with path.open("rb") as handle:
            handle.seek(0, os.SEEK_END)
            handle.seek(max(0, handle.tell() - 64 * 1024))
            text = handle.read().decode(errors="replace")
    except OSError:
        return ""
    return "\n".join(text.splitlines()[-lines:])


# --------------------------------------------------------------------------- the node


class LocalNode:
    """A private RabbitMQ node under ``base_dir``; see the module docstring."""

    def __init__(
        self,
        base_dir: Path | str,
        tls: TlsFiles | None = None,
        tls_only: bool = False,
        rabbitmq: Installation | None = None,
    ) -> None:
        """``tls``: the CA and server certificate the node serves (default: ``tls/`` beside
        ``base_dir``, which is ``$FLEETBUS_DATA_DIR/tls`` for ``$FLEETBUS_DATA_DIR/broker``);
        made at the first start when missing. ``tls_only``: no plain AMQP or HTTP listener, and
        the administrator's URLs are the TLS ones (``FLEETBUS_BROKER_TLS_ONLY``). ``rabbitmq``:
        the installation to run (default: :meth:`installation`)."""
        self.base_dir = Path(base_dir).expanduser().resolve()
        self.tls = tls or TlsFiles.in_folder(self.base_dir.parent / "tls")
        self.tls_only = tls_only
        digest = hashlib.sha1(str(self.base_dir).encode()).hexdigest()[:10]
        self.node_name = f"fleetbus-{digest}@localhost"
        self._proc: subprocess.Popen[bytes] | None = None
        self._node_log_start = 0
        """Where this start's lines begin in the node's log (it is appended to by every start)."""
        self._rabbitmq = rabbitmq

    # paths
    @property
    def node_file(self) -> Path:
        return self.base_dir / "node.json"

    @property
    def admin_file(self) -> Path:
        return self.base_dir / "admin.json"

    @property
    def pid_file(self) -> Path:
        return self.base_dir / "rabbitmq.pid"

    @property
    def log_dir(self) -> Path:
        return self.base_dir / "log"

    @property
    def console_log(self) -> Path:
        """stdout and stderr of ``rabbitmq-server`` (start-up banner, crashes before logging starts)."""
        return self.log_dir / "console.log"

    @property
    def node_log(self) -> Path:
        return self.log_dir / f"{self.node_name}.log"

    @property
    def made_with_file(self) -> Path:
        """Which RabbitMQ made the node's database (a release cannot open a newer one's, and 4.x
        not a 3.x one's): written at each start."""
        return self.base_dir / "rabbitmq.json"

    def __repr__(self) -> str:
        return f"LocalNode({str(self.base_dir)!r})"

    # persistent state
    def ports(self, create: bool = False) -> dict[str, int] | None:
        """The node's ports from ``node.json``; with ``create``, chosen and saved when missing.
        A ``node.json`` of an older version keeps its ports: only the ones it lacks are added."""
        ports: dict[str, int] = {}
        if self.node_file.exists():
            data = json.loads(self.node_file.read_text())
            ports = {name: int(data["ports"][name]) for name in PORT_NAMES if name in data.get("ports", {})}
            if len(ports) == len(PORT_NAMES):
                return ports
            if not create and all(name in ports for name in PORT_NAMES if name not in TLS_PORT_NAMES):
                return ports  # an older node.json: its node has no TLS listeners
        if not create:
            return None
        missing = [name for name in PORT_NAMES if name not in ports]
        fresh = [port for port in choose_free_ports(len(missing) + len(ports)) if port not in ports.values()]
        ports.update(zip(missing, fresh, strict=False))
        ports = {name: ports[name] for name in PORT_NAMES}
        private_dir(self.base_dir)
        self._save_ports(ports)
        return ports

    def _save_ports(self, ports: dict[str, int]) -> None:
        _write_if_changed(
            self.node_file, json.dumps({"node_name": self.node_name, "ports": ports}, indent=2) + "\n"
        )

    def admin_credentials(self, create: bool = False) -> tuple[str, str] | None:
        if self.admin_file.exists():
            data = json.loads(self.admin_file.read_text())
            return data["username"], data["password"]
        if not create:
            return None
        password = secrets.token_urlsafe(24)
        private_dir(self.base_dir)
        write_private_file(self.admin_file, json.dumps({"username": ADMIN_USER, "password": password}) + "\n")
        return ADMIN_USER, password

    # the RabbitMQ it runs
    def _has_database(self) -> bool:
        return any((self.base_dir / "mnesia").glob("*"))

    def made_with(self) -> tuple[Installation, str | None] | None:
        """The installation and the release that last ran the node's database; None for a node
        never started. A node of an older fleetbus, which always ran the host's package, has no
        record: the host's it is."""
        with contextlib.suppress(OSError, ValueError, KeyError):
            data = json.loads(self.made_with_file.read_text())
            return Installation(Path(data["root"])), data.get("version")
        if self._has_database():
            host = Installation(HOST_ROOT)
            return host, host.version()
        return None

    def installation(self) -> Installation:
        """The RabbitMQ this node runs: the one it was given, else ``FLEETBUS_RABBITMQ_ROOT``'s,
        else the one that last ran its database (still installed), else the default
        (:func:`fleetbus_dev.rabbitmq.default_installation`)."""
        if self._rabbitmq is None:
            from fleetbus.settings import load_settings

            explicit = load_settings().rabbitmq_root
            made = self.made_with()
            if explicit is not None:
                self._rabbitmq = Installation(explicit)
            elif made is not None and made[0].exists():
                self._rabbitmq = made[0]
            else:
                self._rabbitmq = default_installation()
        return self._rabbitmq

    def _check_release(self, rabbitmq: Installation) -> None:
        """Refuse to start a database with a release that cannot open it: an older one than made
        it, or one of another major version (4.x does not open a 3.x database)."""
        made = self.made_with() if self._has_database() else None
        version = rabbitmq.version()
        if made is None or made[1] is None or version is None:
            return
        old, new = version_key(made[1]), version_key(version)
        if new[:2] >= old[:2] and new[0] == old[0]:
            return
        where = f"FLEETBUS_RABBITMQ_ROOT={made[0].root}"
        if not made[0].exists():
            where += (
                " (`bash scripts/rabbitmq-root` builds Debian 13's there again)"
                if made[0].chrooted
                else " (`apt-get install rabbitmq-server` installs it again)"
            )
        raise LocalNodeError(
            f"the node in {self.base_dir} was last run by RabbitMQ {made[1]}, and {rabbitmq.describe()} "
            f"cannot open its database (RabbitMQ 4 does not read a 3.x database, and no release reads a "
            f"newer one's). Run it with {where}; or give this RabbitMQ a folder of its own "
            f"(FLEETBUS_DATA_DIR); or start afresh, losing the node's queues, messages and accounts: "
            f"`fleetbus broker down`, delete {self.base_dir / 'mnesia'}, then `bash scripts/setup`"
        )

    def _record_release(self, rabbitmq: Installation) -> None:
        _write_if_changed(
            self.made_with_file,
            json.dumps({"root": str(rabbitmq.root), "version": rabbitmq.version()}, indent=2) + "\n",
        )

    def _shared_folders(self) -> list[Path]:
        """What a node in a root must see: its folder and its TLS files' (the CA's revocation list)."""
        tls = self.tls
        return [self.base_dir, tls.ca.parent, tls.cert.parent, tls.key.parent, tls.crl_dir]

    def _urls(self) -> tuple[str | None, str | None]:
        ports, creds = self.ports(), self.admin_credentials()
        if ports is None or creds is None:
            return None, None
        if self.tls_only:
            return self._amqps_url(), f"https://{HOST}:{ports['management_tls']}/"
        user, password = (quote(part, safe="") for part in creds)
        return (
            f"amqp://{user}:{password}@{HOST}:{ports['amqp']}/",
            f"http://{HOST}:{ports['management']}/",
        )

    def public_url(self) -> str | None:
        """The node's AMQPS listener as a robot on this machine reaches it (no credentials)."""
        port = (self.ports() or {}).get("amqps")
        if port is None:
            return None
        return f"amqps://{HOST}:{port}/?cacertfile={quote(str(self.tls.ca), safe='/')}"

    def _amqps_url(self) -> str | None:
        public, creds = self.public_url(), self.admin_credentials()
        if public is None or creds is None:
            return None
        user, password = (quote(part, safe="") for part in creds)
        return public.replace("amqps://", f"amqps://{user}:{password}@", 1)

    def env(self) -> dict[str, str]:
        """The whole environment of the server and of its CLI tools: the one place that makes the
        node private. Inherited ``RABBITMQ_*`` and ``ERL_*`` variables are dropped."""
        ports = self.ports(create=True)
        assert ports is not None
        base = self.base_dir
        env = {k: v for k, v in os.environ.items() if not k.startswith(("RABBITMQ_", "ERL_"))}
        env.update(
            HOME=str(base),
            LANG="C.UTF-8",
            LC_ALL="C.UTF-8",
            RABBITMQ_CONF_ENV_FILE=str(base / "rabbitmq-env.conf"),
            RABBITMQ_CONFIG_FILE=str(base / "rabbitmq.conf"),
            RABBITMQ_CONFIG_FILES=str(base / "conf.d"),
            RABBITMQ_ADVANCED_CONFIG_FILE=str(base / "advanced.config"),
            RABBITMQ_ENABLED_PLUGINS_FILE=str(base / "enabled_plugins"),
            RABBITMQ_NODENAME=self.node_name,
            RABBITMQ_DIST_PORT=str(ports["dist"]),
            ERL_EPMD_PORT=str(ports["epmd"]),
            ERL_EPMD_ADDRESS=HOST,
            RABBITMQ_MNESIA_BASE=str(base / "mnesia"),
            RABBITMQ_LOG_BASE=str(self.log_dir),
            RABBITMQ_PID_FILE=str(self.pid_file),
            RABBITMQ_PLUGINS_EXPAND_DIR=str(base / "plugins-expand"),
            RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS="-kernel inet_dist_use_interface {127,0,0,1}",
            # the CLI tools are Erlang nodes too: loopback only, any free port
            RABBITMQ_CTL_ERL_ARGS="-kernel inet_dist_use_interface {127,0,0,1}",
            RABBITMQ_CTL_DIST_PORT_MIN="0",
            RABBITMQ_CTL_DIST_PORT_MAX="0",
            **self.installation().env(),
        )
        if not self.tls_only:
            env.update(RABBITMQ_NODE_IP_ADDRESS=HOST, RABBITMQ_NODE_PORT=str(ports["amqp"]))
        return env

    def _write_config(self) -> None:
        ports = self.ports(create=True)
        creds = self.admin_credentials(create=True)
        assert ports is not None and creds is not None
        user, password = creds
        base = self.base_dir
        for folder in (base, self.log_dir, base / "mnesia", base / "conf.d", base / "plugins-expand"):
            private_dir(folder)
        _write_if_changed(
            base / "rabbitmq-env.conf",
            "# Shadows /etc/rabbitmq/rabbitmq-env.conf: fleetbus sets everything in the environment.\n",
        )
        _write_if_changed(base / "enabled_plugins", "[" + ",".join(PLUGINS) + "].\n")
        ensure_certificates(self.tls)
        tls = self.tls
        plain = (
            "listeners.tcp = none\n"
            if self.tls_only
            else f"management.tcp.ip = {HOST}\nmanagement.tcp.port = {ports['management']}\n"
        )
        conf = f"""\
# Written by fleetbus (dev/fleetbus_dev/local_node.py) on every start; edits are overwritten.
{plain}management.ssl.ip = {HOST}
management.ssl.port = {ports["management_tls"]}
management.ssl.cacertfile = {tls.ca}
management.ssl.certfile = {tls.cert}
management.ssl.keyfile = {tls.key}
{rabbitmq_conf(MANAGEMENT)}listeners.ssl.default = {HOST}:{ports["amqps"]}
{CERTIFICATE_LOGIN}stream.listeners.tcp.1 = {HOST}:{ports["stream"]}
default_vhost = /
default_user = {user}
default_pass = {password}
default_user_tags.administrator = true
default_permissions.configure = .*
default_permissions.read = .*
default_permissions.write = .*
loopback_users = none
log.file.level = info
log.console = false
"""
        files = ((base / "rabbitmq.conf", conf), (base / "advanced.config", self._advanced_config()))
        for path, text in files:
            if not path.exists() or path.read_text() != text:
                if self.pid() is not None:
                    log.warning(
                        "the private node's configuration changed (%s): it takes effect when the node "
                        "starts again (`fleetbus broker down`, then `up`)",
                        path,
                    )
                write_private_file(path, text)
        cookie = base / ".erlang.cookie"
        if not cookie.exists():
            write_private_file(cookie, secrets.token_hex(20).upper(), mode=0o400)

    def _advanced_config(self) -> str:
        """The AMQPS listener's TLS options, with the TLS profile
        (:mod:`fleetbus.broker.tls_profile`). They live here, not in rabbitmq.conf, because the
        revocation list's folder (``crl_cache``) can only be given in this file, and RabbitMQ
        takes a listener's ``ssl_options`` from one file or the other, never merged.

        Client certificates are checked against the CA's revocation list when there is one
        (fleetbus's CA always has one; :mod:`fleetbus.broker.revocation`)."""
        tls = self.tls
        options = [
            f"{{cacertfile, {_erlang_string(tls.ca)}}}",
            f"{{certfile, {_erlang_string(tls.cert)}}}",
            f"{{keyfile, {_erlang_string(tls.key)}}}",
            "{verify, verify_peer}",
            "{fail_if_no_peer_cert, false}",
            *erlang_terms(),
        ]
        if ensure_crl(tls):
            folder = _erlang_string(tls.crl_dir)
            cache = f"{{crl_cache, {{ssl_crl_hash_dir, {{internal, [{{dir, {folder}}}]}}}}}}"
            options += ["{crl_check, peer}", cache]
        joined = ",\n    ".join(options)
        return (
            "%% Written by fleetbus (dev/fleetbus_dev/local_node.py) on every start; edits are overwritten.\n"
            f"[{{rabbit, [{{ssl_options, [\n    {joined}\n]}}]}}].\n"
        )

    @contextlib.contextmanager
    def _lock(self, timeout: float) -> Iterator[None]:
        """Serialise up/down between processes (a test run and `fleetbus broker up`, say)."""
        private_dir(self.base_dir)
        with open(private_file(self.base_dir / ".lock"), "w") as handle:
            waiting = retrying(
                f"the lock {self.base_dir / '.lock'} (another process starts or stops the node)",
                on=_LockBusy,
                deadline=timeout,
                backoff=Backoff(initial=0.1, maximum=1.0, jitter=0.1),
                logger=log,
            )
            try:
                waiting(_lock_now, handle)
            except GaveUp:
                raise LocalNodeError(
                    f"another process holds {self.base_dir / '.lock'} (starting or stopping the node)"
                ) from None
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    # processes
    def _is_our_beam(self, pid: int, require_env: bool = False) -> bool:
        """``pid`` is this node's server VM: a beam with our node name that is not a CLI tool
        (rabbitmqctl runs in a beam with the same environment, started through escript)."""
        if not pid_alive(pid) or not _comm(pid).startswith("beam"):
            return False
        if _is_escript(pid):
            return False
        env = _environ(pid)
        if env is None:
            return not require_env
        return env.get("RABBITMQ_NODENAME") == self.node_name

    def pid(self) -> int | None:
        """PID of the node's Erlang VM (beam) when it runs, else None."""
        with contextlib.suppress(OSError, ValueError):
            pid = int(self.pid_file.read_text().strip())
            if self._is_our_beam(pid):
                return pid
        # no (or a stale) pid file: the node may still run, e.g. while it is starting
        for pid in psutil.pids():
            if self._is_our_beam(pid, require_env=True):
                return pid
        return None

    def epmd_pids(self) -> list[int]:
        ports = self.ports()
        if ports is None:
            return []
        return [pid for pid in pids_listening_on(ports["epmd"]) if _comm(pid) == "epmd"]

    def status(self) -> NodeInfo:
        pid = self.pid()
        amqp_url, management_url = self._urls()
        ports = self.ports() or {}
        tls = pid is not None and self._tls_listening(pid)
        return NodeInfo(
            running=pid is not None,
            pid=pid,
            node_name=self.node_name,
            base_dir=self.base_dir,
            amqp_url=amqp_url,
            management_url=management_url,
            ports=ports,
            log_file=self.node_log,
            amqps_url=self._amqps_url() if tls else None,
            public_url=self.public_url() if tls else None,
            management_tls_url=f"https://{HOST}:{ports['management_tls']}/" if tls else None,
        )

    def _tls_listening(self, pid: int) -> bool:
        """Whether the running node listens on its AMQPS port (one started by an older version,
        with another configuration, does not until it starts again)."""
        port = (self.ports() or {}).get("amqps")
        return port is not None and port in {listening for _, listening in listening_addresses(pid)}

    def ready(self, timeout: float = 3.0) -> bool:
        """Whether the administrator can log in over AMQP and the management API answers."""
        amqp_url, management_url = self._urls()
        creds = self.admin_credentials()
        if amqp_url is None or management_url is None or creds is None:
            return False
        return bool(amqp_login(amqp_url, timeout)) and management_answers(management_url, *creds, timeout)

    def rabbitmqctl(
        self, *args: str, timeout: float = 60.0, check: bool = True, stdin: str | None = None
    ) -> subprocess.CompletedProcess[str]:
        """Run ``rabbitmqctl ARGS`` against this node; raises LocalNodeError when it fails and
        ``check``. ``stdin``: what it reads (a password: never on a command line, which every user
        of the machine sees)."""
        return self._tool("rabbitmqctl", args, timeout, check, stdin)

    def rabbitmq_plugins(
        self, *args: str, timeout: float = 60.0, check: bool = True
    ) -> subprocess.CompletedProcess[str]:
        """Run ``rabbitmq-plugins ARGS`` for this node (``enable --online NAME``...)."""
        return self._tool("rabbitmq-plugins", args, timeout, check)

    def _tool(
        self, tool: str, args: tuple[str, ...], timeout: float, check: bool, stdin: str | None = None
    ) -> subprocess.CompletedProcess[str]:
        rabbitmq = self._require_installation()
        try:
            result = subprocess.run(
                rabbitmq.command(tool, args, self._shared_folders(), self.base_dir),
                env=self.env(),
                cwd=self.base_dir,
                input=stdin if stdin is not None else "",
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        except subprocess.TimeoutExpired as error:
            raise LocalNodeError(f"{tool} {' '.join(args)} did not finish in {timeout:.0f} s") from error
        if check and result.returncode != 0:
            raise LocalNodeError(
                f"{tool} {' '.join(args)} failed ({result.returncode}): "
                f"{(result.stderr or result.stdout).strip()}"
            )
        return result

    def _require_installation(self) -> Installation:
        rabbitmq = self.installation()
        try:
            rabbitmq.require()
        except InstallationError as error:
            raise LocalNodeError(str(error)) from None
        return rabbitmq

    def _startup_failure(self, message: str) -> LocalNodeError:
        parts = [message]
        for path in (self.console_log, self.node_log):
            tail = _tail(path)
            if tail:
                parts.append(f"--- last lines of {path} ---\n{tail}")
        return LocalNodeError("\n".join(parts))

    def _check_ports(self, ports: dict[str, int]) -> None:
        """Before a start: every port but epmd's must be free (ours may take a moment to go)."""
        names = [name for name in PORT_NAMES if name != "epmd"]

        def busy() -> list[str]:
            return [name for name in names if not _port_free(ports[name])]

        if _wait_until(lambda: not busy(), timeout=10, interval=0.2):
            return
        taken = busy()
        if taken and set(taken) <= set(UNPUBLISHED_PORTS):
            self._move_ports(taken)
            self._write_config()
            moved = ", ".join(taken)
            log.warning("ports of the private node %s were taken meanwhile; %s moved", self.node_name, moved)
            return
        if taken:
            listed = ", ".join(f"{name} {ports[name]}" for name in taken)
            raise LocalNodeError(
                f"ports of the private node are taken by another program ({listed}); "
                f"stop it, or delete {self.node_file} to choose new ports"
            )

    def up(self, timeout: float = 90.0) -> NodeInfo:
        """Start the node unless it runs; return once the admin can log in (AMQP and HTTP)."""
        self._require_installation()
        deadline = time.monotonic() + timeout
        with self._lock(timeout):
            # a database made by this start has no queues yet, let alone leaderless ones
            had_database = any((self.base_dir / "mnesia").glob("*"))
            if self.pid() is None:
                self._check_release(self.installation())
            self._write_config()
            pid = self.pid()
            started = pid is None
            if started:
                self._start_on_free_ports(deadline, fresh=not had_database)
            else:
                self._wait_ready(deadline, started)
            if started:
                self._record_release(self.installation())
            if not started and pid is not None and not self._tls_listening(pid):
                log.warning(
                    "the private node runs without its AMQPS and HTTPS listeners (it was started by an "
                    "older fleetbus): `fleetbus broker down`, then `up`, to add them"
                )
            if started:
                self._drop_guest()
                if had_database:
                    self.heal_quorum_queues(deadline)
        return self.status()

    def _start_on_free_ports(self, deadline: float, fresh: bool) -> None:
        """Start the node and wait for it. A port is checked free before the start, but another
        process can bind it before the node does; a new node (no database yet, so nobody has been
        given its addresses) then takes new ports and starts again, instead of failing."""
        for attempt in range(1, PORT_RACE_ATTEMPTS + 1):
            self._start()
            try:
                self._wait_ready(deadline, True)
                return
            except LocalNodeError:
                retry = fresh and attempt < PORT_RACE_ATTEMPTS and time.monotonic() < deadline
                if not (retry and self._ended_on_a_taken_port()):
                    raise
            log.warning(
                "a port of the private node %s was taken before it could listen; starting again on new ports",
                self.node_name,
            )
            self._move_ports([name for name in PORT_NAMES if name != "epmd"])  # a cluster shares epmd's
            self._write_config()

    def _move_ports(self, names: list[str]) -> None:
        """New free ports for ``names``; the others kept."""
        old = self.ports()
        assert old is not None
        fresh = iter(port for port in choose_free_ports(len(names) * 2) if port not in old.values())
        self._save_ports({name: (next(fresh) if name in names else port) for name, port in old.items()})

    def _ended_on_a_taken_port(self) -> bool:
        """Whether the start just made ended because a port was taken. Whatever failed first:
        another broker on our AMQP port refuses our login, and repairing the login then finds our
        node gone, before the loop that waits sees the process end (it writes a crash dump first)."""
        proc = self._proc
        if proc is not None:  # a node dying of a taken port may still be booting, or dumping
            if _wait_until(lambda: proc.poll() is not None, timeout=30) is None:
                return False  # it lives on: whatever failed, it was not a port
            self._proc = None
        return self._lost_a_port()

    def _lost_a_port(self) -> bool:
        """Whether the last start lost a listener's port, or the distribution port, to another
        process: said in its console log (written afresh by every start) or, once the node logs
        to its own file, in what this start wrote there. A node that lost a listener's port may
        run on without that listener (RabbitMQ 3.10 does)."""
        texts = []
        with contextlib.suppress(OSError):
            texts.append(self.console_log.read_text(errors="replace"))
        with contextlib.suppress(OSError), open(self.node_log, "rb") as node_log:
            node_log.seek(self._node_log_start)
            texts.append(node_log.read().decode(errors="replace"))
        return any(mark in text for text in texts for mark in PORT_IN_USE_MARKS)

    def heal_quorum_queues(self, deadline: float) -> int:
        """Elect a leader for every quorum queue that came back from a crash without one.

        RabbitMQ can restart a single-node quorum queue with no leader (it answers
        ``INTERNAL_ERROR`` to consumers and its messages look gone; rabbitmq-server #10070),
        mostly one created moments before the crash: seen on 3.10.8 and on 4.0.5. Its messages
        are still on disk: an election brings them back. Returns how many queues needed one.
        """
        healed: set[str] = set()
        while True:
            result = self.rabbitmqctl("eval", _LEADERLESS_QUORUM_QUEUES, check=False, timeout=60)
            names = re.findall(r'"([^"]+)"', result.stdout) if result.returncode == 0 else []
            if not names:
                if healed:
                    log.warning("elected leaders for %d leaderless quorum queues: %s", len(healed), healed)
                return len(healed)
            healed.update(names)
            if time.monotonic() >= deadline:
                log.error("quorum queues still without a leader: %s", names)
                return len(healed)
            time.sleep(0.5)  # elections run in the background; then check again

    def _start(self) -> None:
        rabbitmq = self._require_installation()
        ports = self.ports(create=True)
        assert ports is not None
        self._check_ports(ports)
        with contextlib.suppress(FileNotFoundError):
            self.pid_file.unlink()  # stale after a kill -9
        private_dir(self.log_dir)
        # the node's own log is appended to by every start: only what this start writes counts
        self._node_log_start = self.node_log.stat().st_size if self.node_log.exists() else 0
        log.info(
            "starting the private RabbitMQ node %s in %s (%s)",
            self.node_name,
            self.base_dir,
            rabbitmq.describe(),
        )
        with open(private_file(self.console_log), "wb") as console:
            self._proc = subprocess.Popen(
                rabbitmq.command("rabbitmq-server", (), self._shared_folders(), self.base_dir),
                env=self.env(),
                cwd=self.base_dir,
                stdin=subprocess.DEVNULL,
                stdout=console,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                umask=OWNER_ONLY,  # its database, logs and cookie are its owner's only
            )

    def _wait_ready(self, deadline: float, started: bool) -> None:
        creds = self.admin_credentials()
        amqp_url, management_url = self._urls()
        amqps_url = self._amqps_url()
        assert creds is not None and amqp_url is not None and management_url is not None
        assert amqps_url is not None
        repaired = False
        amqp_ok = False
        while True:
            if self._proc is not None and self._proc.poll() is not None and self.pid() is None:
                self._proc = None
                raise self._startup_failure("the private RabbitMQ node exited while starting")
            if not started and self.pid() is None:
                raise self._startup_failure("the private RabbitMQ node stopped while we waited for it")
            if started and self._lost_a_port():
                self._force_stop()
                raise self._startup_failure("another process took a port of the private node as it started")
            remaining = deadline - time.monotonic()
            if not amqp_ok:
                login = amqp_login(amqp_url, timeout=max(0.5, min(3.0, remaining)))
                if login is False and not repaired:
                    # admin.json and the database disagree (admin.json lost or replaced)
                    self._repair_admin(*creds)
                    repaired = True
                    continue
                amqp_ok = bool(login)
            probe_timeout = max(0.5, min(3.0, remaining))
            if (
                amqp_ok
                and management_answers(management_url, *creds, timeout=probe_timeout)
                and (not started or amqp_login(amqps_url, timeout=probe_timeout))
            ):
                return
            if time.monotonic() >= deadline:
                if started:
                    self._force_stop()
                raise self._startup_failure(
                    "the private RabbitMQ node did not accept the administrator's login (AMQP, AMQPS "
                    "and the management API) in time" + (" (it was stopped again)" if started else "")
                )
            time.sleep(0.2)

    def _repair_admin(self, user: str, password: str) -> None:
        log.warning("resetting the password of %s on the private node from %s", user, self.admin_file)
        listing = self.rabbitmqctl("list_users", "--silent", "--no-table-headers", check=False).stdout
        # the password on standard input: a command line is every local user's to read
        if user not in {line.split("\t")[0].strip() for line in listing.splitlines()}:
            self.rabbitmqctl("add_user", user, stdin=password + "\n")
        else:
            self.rabbitmqctl("change_password", user, stdin=password + "\n")
        self.rabbitmqctl("set_user_tags", user, "administrator")
        self.rabbitmqctl("set_permissions", "-p", "/", user, ".*", ".*", ".*")

    def _drop_guest(self) -> None:
        """Belt and braces: a database made before fleetbus set default_user may have guest."""
        import httpx

        from fleetbus.broker.management import tls_context

        _, management_url = self._urls()
        creds = self.admin_credentials()
        assert management_url is not None and creds is not None
        with contextlib.suppress(httpx.HTTPError):
            url = management_url.rstrip("/") + "/api/users/guest"
            if httpx.get(url, auth=creds, timeout=5, verify=tls_context()).status_code == 200:
                log.warning("deleting the guest account of the private node")
                httpx.delete(url, auth=creds, timeout=5, verify=tls_context())

    def _reap(self) -> None:
        if self._proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=5)
            if self._proc.poll() is not None:
                self._proc = None

    def _force_stop(self) -> None:
        pid = self.pid()
        if pid is not None:
            _signal(pid, signal.SIGKILL)
            if not _wait_until(lambda: not pid_alive(pid), timeout=30):
                raise LocalNodeError(f"the node's process {pid} survived SIGKILL")
        if self._proc is not None and self._proc.poll() is None:
            _signal(self._proc.pid, signal.SIGKILL)
        self._reap()

    def kill(self) -> None:
        """SIGKILL the node's VM (fault injection) and wait until it is gone; epmd stays."""
        pid = self.pid()
        if pid is None:
            return
        _signal(pid, signal.SIGKILL)
        if not _wait_until(lambda: not pid_alive(pid), timeout=30, interval=0.05):
            raise LocalNodeError(f"the node's process {pid} survived SIGKILL")
        self._reap()

    def down(self, timeout: float = 60.0, stop_epmd: bool = True) -> None:
        """Stop the node (``rabbitmqctl shutdown``, SIGKILL if that fails) and, unless ``stop_epmd``
        is False (a cluster's nodes share one epmd), its private epmd."""
        deadline = time.monotonic() + timeout
        with self._lock(timeout):
            pid = self.pid()
            if pid is not None:
                try:
                    self.rabbitmqctl("shutdown", timeout=max(5.0, deadline - time.monotonic() - 5))
                except LocalNodeError as error:
                    log.warning("rabbitmqctl shutdown failed (%s); killing the node", error)
                if not _wait_until(
                    lambda: not pid_alive(pid), timeout=max(1.0, deadline - time.monotonic() - 5)
                ):
                    self._force_stop()
            self._reap()
            with contextlib.suppress(FileNotFoundError):
                self.pid_file.unlink()
            if stop_epmd:
                self._stop_epmd(deadline)

    def _stop_epmd(self, deadline: float) -> None:
        for pid in self.epmd_pids():
            _signal(pid, signal.SIGTERM)
            if not _wait_until(
                lambda pid=pid: not pid_alive(pid), timeout=max(1.0, deadline - time.monotonic())
            ):
                _signal(pid, signal.SIGKILL)
                _wait_until(lambda pid=pid: not pid_alive(pid), timeout=5)
