"""The private RabbitMQ node, for real, in a temporary folder (never the project's .fleetbus).

One node serves the whole module (a start costs about 5 s); the kill test restarts it once and
the last test stops it.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import os
import re
import secrets
import socket
import ssl
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pika
import pytest

from fleetbus.broker.accounts import can_login
from fleetbus.broker.certificates import ClientFiles, TlsFiles, issue_client_certificate, make_certificates
from fleetbus.broker.endpoint import BrokerUnavailable, wait_for_login
from fleetbus.broker.management import ManagementAPI
from fleetbus.broker.tls import aio_connect, shovel_uri
from fleetbus.publishers.client import RobotClient
from fleetbus.publishers.tls import TlsSettingError, blocking_connection
from fleetbus.schemas.routing import EXPRESS_QUEUE, events_exchange
from fleetbus.settings import Settings, load_settings
from fleetbus_dev.fallback import docker_engine_answers, resolve_broker
from fleetbus_dev.local_node import (
    ADMIN_USER,
    PLUGINS,
    TLS_PORT_NAMES,
    LocalNode,
    LocalNodeError,
    amqp_login,
    ensure_certificates,
    listening_addresses,
    pid_alive,
    pids_listening_on,
)
from fleetbus_dev.rabbitmq import mount_points
from tests.factories import hazard
from tests.support import wait_for
from tests.test_revocation import refused_as_revoked


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fleetbus-data")


@pytest.fixture(scope="module")
def node_settings(data_dir: Path) -> Settings:
    return load_settings({"FLEETBUS_DATA_DIR": str(data_dir)})


@pytest.fixture(scope="module")
def module_node(node_settings: Settings) -> Iterator[LocalNode]:
    node = LocalNode(node_settings.broker_dir)
    try:
        yield node
    finally:
        node.down()


@pytest.fixture
def node(module_node: LocalNode) -> LocalNode:
    """The module's node, running (started on first use, or again after the down test)."""
    module_node.up()
    return module_node


def admin(node: LocalNode) -> tuple[str, str]:
    credentials = node.admin_credentials()
    assert credentials is not None
    return credentials


def test_up_is_idempotent(node: LocalNode) -> None:
    first = node.status()
    assert first.running and first.pid is not None
    started = time.monotonic()
    again = node.up()
    assert time.monotonic() - started < 30, "no restart: a login and a look, not a start"
    assert again.pid == first.pid == node.pid()
    assert again.amqp_url == first.amqp_url


def test_status_shows_urls_and_keeps_state_in_its_folder(node: LocalNode) -> None:
    info = node.status()
    ports = json.loads(node.node_file.read_text())["ports"]
    assert set(ports) == {"amqp", "management", "dist", "epmd", "stream", "amqps", "management_tls"}
    assert len(set(ports.values())) == 7
    assert info.ports == ports
    assert info.amqp_url is not None
    match = re.fullmatch(r"amqp://fleetbus-admin:([^@]+)@127\.0\.0\.1:(\d+)/", info.amqp_url)
    assert match and int(match[2]) == ports["amqp"]
    assert match[1] == admin(node)[1]
    assert info.management_url == f"http://127.0.0.1:{ports['management']}/"
    assert info.node_name.startswith("fleetbus-") and info.node_name.endswith("@localhost")
    assert stat.S_IMODE(node.admin_file.stat().st_mode) == 0o600
    assert (node.base_dir / ".erlang.cookie").exists()  # HOME is the node's folder
    assert node.pid_file.read_text().strip() == str(info.pid)
    assert "rabbitmq_management" in (node.base_dir / "enabled_plugins").read_text()


def test_admin_logs_in_and_there_is_no_guest(node: LocalNode) -> None:
    info = node.status()
    assert info.amqp_url is not None and info.management_url is not None
    assert amqp_login(info.amqp_url) is True
    port = info.ports["amqp"]
    assert amqp_login(f"amqp://guest:guest@127.0.0.1:{port}/") is False
    users = httpx.get(info.management_url + "api/users", auth=admin(node), timeout=10)
    assert users.status_code == 200
    assert [user["name"] for user in users.json()] == [ADMIN_USER]
    assert "administrator" in str(users.json()[0]["tags"])
    guest = httpx.get(info.management_url + "api/overview", auth=("guest", "guest"), timeout=10)
    assert guest.status_code == 401
    listing = node.rabbitmqctl("list_users", "--silent", "--no-table-headers").stdout
    assert ADMIN_USER in listing and "guest" not in listing


def test_listens_only_on_loopback(node: LocalNode) -> None:
    info = node.status()
    assert info.pid is not None
    beam = listening_addresses(info.pid)
    assert {port for _, port in beam} >= {
        info.ports[name] for name in ("amqp", "management", "dist", "amqps", "management_tls")
    }
    epmds = node.epmd_pids()
    assert epmds, "the node's private epmd is not running"
    assert {host for host, _ in beam} == {"127.0.0.1"}, beam
    epmd = [address for pid in epmds for address in listening_addresses(pid)]
    assert all(ipaddress.ip_address(host).is_loopback for host, _ in epmd), epmd  # 127.0.0.1 and ::1
    assert {port for _, port in listening_addresses(epmds[0])} == {info.ports["epmd"]}


def test_the_node_runs_its_installation_and_mounts_nothing_on_the_host(node: LocalNode) -> None:
    """A node in a root (``FLEETBUS_RABBITMQ_ROOT``) runs chrooted with its folders mounted in a
    namespace of its own; the host's mount table never holds them, so nothing is left behind."""
    rabbitmq = node.installation()
    pid = node.pid()
    assert pid is not None
    assert os.readlink(f"/proc/{pid}/root") == str(rabbitmq.root)
    assert rabbitmq.version() in node.rabbitmqctl("status").stdout
    if rabbitmq.chrooted:  # the node's mount table, as it sees it from inside its root
        inside = {line.split()[4] for line in Path(f"/proc/{pid}/mountinfo").read_text().splitlines()}
        assert {"/proc", "/dev", *(str(folder) for folder in mount_points([node.base_dir]))} <= inside
        assert str(rabbitmq.root) not in Path("/proc/self/mountinfo").read_text()
    assert json.loads(node.made_with_file.read_text()) == {
        "root": str(rabbitmq.root),
        "version": rabbitmq.version(),
    }


def _declare(url: str, queue: str) -> None:
    connection = blocking_connection(url)
    try:
        connection.channel().queue_declare(queue, durable=True)
    finally:
        connection.close()


def _publish(url: str, queue: str, bodies: list[bytes]) -> None:
    connection = blocking_connection(url)
    try:
        channel = connection.channel()
        channel.confirm_delivery()
        for body in bodies:
            channel.basic_publish(
                "", queue, body, pika.BasicProperties(delivery_mode=pika.DeliveryMode.Persistent)
            )
    finally:
        connection.close()


def _ready(url: str, queue: str) -> int | None:
    """Messages ready in ``queue``; None while the node is not answering or still recovering it."""
    try:
        connection = blocking_connection(url)
    except pika.exceptions.AMQPError:
        return None
    try:
        return connection.channel().queue_declare(queue, passive=True).method.message_count
    except pika.exceptions.ChannelClosedByBroker as error:
        if error.reply_code == 404:  # a restarted node answers NOT_FOUND until it recovered the queue
            return None
        raise
    finally:
        if connection.is_open:
            connection.close()


def _drain(url: str, queue: str) -> list[bytes]:
    connection = blocking_connection(url)
    bodies: list[bytes] = []
    try:
        channel = connection.channel()
        while True:
            method, _, body = channel.basic_get(queue, auto_ack=True)
            if method is None:
                return bodies
            bodies.append(body)
    finally:
        connection.close()


@pytest.mark.rabbitmq_versions  # a quorum queue's recovery from a crash differs between releases
def test_kill_then_up_keeps_durable_persistent_messages(node: LocalNode) -> None:
    url = node.status().amqp_url
    assert url is not None
    _declare(url, "kill-test")
    # A queue declared seconds before a SIGKILL can be lost with its messages: RabbitMQ 3.10 writes
    # its metadata (Mnesia's log) lazily; seen once in a full suite run ("Recovering 0 queues"
    # after the kill). A clean restart writes it; what is tested is that confirmed messages survive.
    node.down()
    before = node.up()
    assert before.amqp_url == url and before.pid is not None
    bodies = [f"message {i}".encode() for i in range(300)]
    _publish(url, "kill-test", bodies)

    node.kill()
    assert not pid_alive(before.pid)
    assert not node.status().running
    assert node.pid_file.exists()  # stale: up() must cope with it

    after = node.up()
    assert after.running and after.pid != before.pid
    assert after.ports == before.ports and after.amqp_url == before.amqp_url
    wait_for(
        lambda: _ready(after.amqp_url or "", "kill-test") == len(bodies), 30, "the 300 messages after restart"
    )
    assert sorted(_drain(after.amqp_url, "kill-test")) == sorted(bodies)


def test_resolve_broker_prefers_a_working_amqp_url(node: LocalNode, node_settings: Settings) -> None:
    info = node.status()
    assert info.amqp_url is not None and info.management_url is not None
    external = resolve_broker(
        node_settings.updated(amqp_url=info.amqp_url, management_url=info.management_url), start=False
    )
    assert (external.kind, external.amqp_url, external.management_url) == (
        "external",
        info.amqp_url,
        info.management_url,
    )
    derived = resolve_broker(node_settings.updated(amqp_url=info.amqp_url, management_url=None), start=False)
    assert derived.management_url == "http://127.0.0.1:15672/"

    parts = urlsplit(info.amqp_url)
    wrong = info.amqp_url.replace(f":{parts.password}@", ":not-the-password@")
    with pytest.raises(BrokerUnavailable, match="refused"):
        resolve_broker(node_settings.updated(amqp_url=wrong), start=False)


def test_a_configured_broker_that_does_not_answer_is_an_error_never_a_fallback(
    node: LocalNode, node_settings: Settings, tmp_path: Path
) -> None:
    """The private node runs, and is not used in place of the configured broker; nor is a new one
    started for a data folder that has none."""
    dead = f"amqp://someone:secret@127.0.0.1:{node.status().ports['stream']}/"  # nothing listens there
    for data_dir in (node_settings.data_dir, tmp_path):
        settings = node_settings.updated(data_dir=data_dir, amqp_url=dead, broker_wait_s=1.5)
        started = time.monotonic()
        with pytest.raises(
            BrokerUnavailable, match=r"someone:\*\*\*\*@127.0.0.1:\d+/\) did not answer"
        ) as raised:
            resolve_broker(settings, start=True)
        assert 1.5 <= time.monotonic() - started < 15
        assert "secret" not in str(raised.value)
    assert not (tmp_path / "broker").exists(), "a private node was made for the configured broker"


@pytest.mark.skipif(docker_engine_answers(), reason="a Docker engine answers: resolve_broker would use it")
def test_with_nothing_configured_the_private_node_is_used(node: LocalNode, node_settings: Settings) -> None:
    endpoint = resolve_broker(node_settings.updated(amqp_url=None), start=False)
    assert endpoint.kind == "private"
    assert endpoint.amqp_url == node.status().amqp_url


def test_broker_status_masks_the_password_unless_asked(node: LocalNode, node_settings: Settings) -> None:
    env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(node_settings.data_dir), COLUMNS="200")
    password = admin(node)[1]

    def status(*options: str) -> str:
        command = [sys.executable, "-m", "fleetbus", "broker", "status", *options]
        result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr
        return result.stdout

    masked = status()
    assert password not in masked
    assert f"amqp://{ADMIN_USER}:****@127.0.0.1:{node.status().ports['amqp']}/" in masked
    assert str(node.admin_file) in masked, "it says where the password is kept"
    assert node.status().amqp_url in status("--show-password")


def _peer_names(port: int, ca: Path, server_name: str = "127.0.0.1") -> list[str]:
    """A real TLS handshake with the node, verified against ``ca``: the names its certificate carries."""
    context = ssl.create_default_context(cafile=str(ca))
    with (
        socket.create_connection(("127.0.0.1", port), timeout=10) as raw,
        context.wrap_socket(raw, server_hostname=server_name) as tls,
    ):
        certificate = tls.getpeercert()
    return [value for _, value in certificate["subjectAltName"]]


def test_the_node_serves_its_certificate_on_amqps_and_the_management_api(node: LocalNode) -> None:
    info = node.status()
    assert node.tls.ca == node.base_dir.parent / "tls" / "ca.pem"  # made at the first start
    assert stat.S_IMODE(node.tls.key.stat().st_mode) == 0o600
    for port in (info.ports["amqps"], info.ports["management_tls"]):
        assert _peer_names(port, node.tls.ca) == ["localhost", "127.0.0.1"]
    assert info.management_tls_url == f"https://127.0.0.1:{info.ports['management_tls']}/"
    overview = httpx.get(
        info.management_tls_url + "api/overview",
        auth=admin(node),
        timeout=10,
        verify=ssl.create_default_context(cafile=str(node.tls.ca)),
    )
    assert overview.status_code == 200
    with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
        httpx.get(info.management_tls_url + "api/overview", timeout=10)  # the system's CAs do not know it
    assert info.amqps_url is not None and amqp_login(info.amqps_url) is True
    assert info.public_url == (f"amqps://127.0.0.1:{info.ports['amqps']}/?cacertfile={node.tls.ca}")


def test_the_management_client_verifies_an_https_api_with_fleetbus_ca(
    node: LocalNode, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    info = node.status()
    assert info.management_tls_url is not None
    monkeypatch.setenv("FLEETBUS_TLS_CA", str(node.tls.ca))
    with ManagementAPI(info.management_tls_url, *admin(node)) as api:
        assert ADMIN_USER in [user["name"] for user in api.list_users()]
    other = TlsFiles.in_folder(tmp_path / "other")
    make_certificates(other)
    monkeypatch.setenv("FLEETBUS_TLS_CA", str(other.ca))
    with ManagementAPI(info.management_tls_url, *admin(node)) as api:
        with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
            api.list_users()


def test_a_node_json_without_the_tls_ports_keeps_its_ports(tmp_path: Path) -> None:
    """A node made by an older version keeps the ports robots and tools know; only the new ones
    are chosen (no node is started)."""
    old = LocalNode(tmp_path / "broker")
    old.base_dir.mkdir(parents=True)
    kept = {"amqp": 23001, "management": 23002, "dist": 23003, "epmd": 23004, "stream": 23005}
    old.node_file.write_text(json.dumps({"node_name": old.node_name, "ports": kept}))
    assert old.ports() == kept  # what the running node of that version listens on
    ports = old.ports(create=True)
    assert ports is not None and {name: ports[name] for name in kept} == kept
    assert len(set(ports.values())) == len(ports) == len(kept) + 2
    assert json.loads(old.node_file.read_text())["ports"] == ports


@pytest.fixture
def robot_url(node: LocalNode, node_settings: Settings) -> Iterator[str]:
    """A robot account made by `fleetbus users add` with nothing configured (the private node):
    the URL it hands out."""
    env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(node_settings.data_dir), COLUMNS="300")
    command = [sys.executable, "-m", "fleetbus", "users", "add", "tls-explorer", "--kind", "explorer"]
    added = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    assert added.returncode == 0, added.stderr
    [url] = [line for line in added.stdout.splitlines() if line.startswith("amqp")]
    assert f"the CA {node.tls.ca}" in added.stdout, "it says where the robot's CA is"
    try:
        yield url
    finally:
        removed = _users(node_settings, "remove", "tls-explorer")  # from the registry too
        assert removed.returncode == 0, removed.stderr


def test_users_add_hands_out_an_amqps_url_the_robot_client_publishes_with(
    robot_url: str, node: LocalNode, tmp_path: Path
) -> None:
    info = node.status()
    assert robot_url.startswith("amqps://tls-explorer:")
    assert robot_url.endswith(f"@127.0.0.1:{info.ports['amqps']}/?cacertfile={node.tls.ca}")
    admin_url = info.amqp_url or ""
    before = _ready(admin_url, EXPRESS_QUEUE)
    with RobotClient(robot_url, state_dir=tmp_path, connect_timeout=20) as robot:
        robot.connect()
        robot.publish("hazard", hazard())
        assert robot.flush(timeout=20)
    wait_for(lambda: _ready(admin_url, EXPRESS_QUEUE) == before + 1, 20, "the hazard in the express lane")


@pytest.mark.parametrize(
    ("change", "refusal"),
    [
        ("another CA", "CERTIFICATE_VERIFY_FAILED"),
        ("a name not in the certificate", "Hostname mismatch, certificate is not valid for 'broker.example'"),
    ],
)
def test_the_robot_client_refuses_a_broker_it_cannot_verify(
    robot_url: str, tmp_path: Path, node: LocalNode, change: str, refusal: str
) -> None:
    if change == "another CA":
        other = TlsFiles.in_folder(tmp_path / "other")
        make_certificates(other)
        url = robot_url.replace(str(node.tls.ca), str(other.ca))
    else:
        url = robot_url + "&server_name_indication=broker.example"
    with RobotClient(url, state_dir=tmp_path / "robot", connect_timeout=60) as robot:
        started = time.monotonic()
        with pytest.raises(BrokerUnavailable, match="certificate verify failed") as refused:
            robot.connect()
        assert refusal in str(refused.value)
        # trying again cannot verify it either: said at the first refusal, not after the timeout
        assert time.monotonic() - started < 30


def _users(node_settings: Settings, *args: str) -> subprocess.CompletedProcess[str]:
    """`fleetbus users ARGS` with the node's settings only."""
    env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(node_settings.data_dir), COLUMNS="400")
    command = [sys.executable, "-m", "fleetbus", "users", *args]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)


def _add_cert_robot(node: LocalNode, node_settings: Settings, name: str) -> tuple[str, str]:
    """`fleetbus users add NAME --cert` on the private node: the URL it hands out, and what it said."""
    added = _users(node_settings, "add", name, "--kind", "explorer", "--cert")
    assert added.returncode == 0, added.stderr
    [url] = [line for line in added.stdout.splitlines() if line.startswith("amqp")]
    return url, added.stdout


@pytest.fixture
def cert_robots(node: LocalNode, node_settings: Settings) -> Iterator[dict[str, str]]:
    """Two robots made by `fleetbus users add --cert`: their URLs by name."""
    urls = {name: _add_cert_robot(node, node_settings, name)[0] for name in ("cert-scout", "cert-rover")}
    try:
        yield urls
    finally:
        for name in urls:
            removed = _users(node_settings, "remove", name)  # from the registry too
            assert removed.returncode == 0, removed.stderr


def _management(node: LocalNode) -> ManagementAPI:
    info = node.status()
    assert info.management_url is not None
    return ManagementAPI(info.management_url, *admin(node))


def test_users_add_cert_hands_out_a_certificate_url_the_robot_client_publishes_with(
    cert_robots: dict[str, str], node: LocalNode, tmp_path: Path
) -> None:
    info = node.status()
    clients = node.tls.clients
    url = cert_robots["cert-scout"]
    assert url == (
        f"amqps://cert-scout@127.0.0.1:{info.ports['amqps']}/?cacertfile={node.tls.ca}"
        f"&certfile={clients / 'cert-scout.pem'}&keyfile={clients / 'cert-scout.key'}&auth_mechanism=external"
    )
    assert stat.S_IMODE((clients / "cert-scout.key").stat().st_mode) == 0o600
    admin_url = info.amqp_url or ""
    before = _ready(admin_url, EXPRESS_QUEUE)
    with RobotClient(url, state_dir=tmp_path, connect_timeout=20) as robot, _management(node) as api:
        robot.connect()
        robot.publish("hazard", hazard())
        assert robot.flush(timeout=20)  # the broker confirmed it, user_id and all

        def logins() -> list[tuple[str, str]]:
            return [(c.get("user", ""), c.get("auth_mechanism", "")) for c in api.list_connections()]

        wait_for(lambda: ("cert-scout", "EXTERNAL") in logins(), 20, "the robot's connection, as cert-scout")
    wait_for(lambda: _ready(admin_url, EXPRESS_QUEUE) == before + 1, 20, "the hazard in the express lane")


def test_a_worker_style_aio_pika_connection_logs_in_with_the_certificate_too(
    cert_robots: dict[str, str], node: LocalNode
) -> None:
    async def who_am_i() -> None:
        connection = await aio_connect(cert_robots["cert-rover"])
        try:
            channel = await connection.channel()
            await channel.declare_exchange(events_exchange("cert-rover"), passive=True)
            with _management(node) as api:
                wait_for(
                    lambda: any(
                        c.get("user") == "cert-rover" and c.get("auth_mechanism") == "EXTERNAL"
                        for c in api.list_connections()
                    ),
                    20,
                    "the aio-pika connection, as cert-rover",
                )
        finally:
            await connection.close()

    asyncio.run(who_am_i())


def test_a_certificate_account_has_no_password(
    cert_robots: dict[str, str], node: LocalNode, node_settings: Settings
) -> None:
    with _management(node) as api:
        user = api.get_user("cert-scout")
    assert user is not None and user["password_hash"] == ""
    env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
    env.update(FLEETBUS_DATA_DIR=str(node_settings.data_dir), COLUMNS="200")
    listed = subprocess.run(
        [sys.executable, "-m", "fleetbus", "users", "list", "--json"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert listed.returncode == 0, listed.stderr
    # the registry's users (a password's login is listed in tests/api/test_one_registry.py)
    logins = {user["name"]: user["login"] for user in json.loads(listed.stdout)["users"]}
    assert logins["cert-scout"] == "certificate" and ADMIN_USER not in logins
    public = node.status().public_url or ""
    for password in ("", "guess", admin(node)[1]):
        plain = public.replace("amqps://", f"amqps://cert-scout:{password}@", 1)
        assert amqp_login(plain) is False, f"a PLAIN login with {password!r}"
    # the certificate presented but a password asked for: still PLAIN, still refused
    with_cert = cert_robots["cert-scout"].replace("cert-scout@", "cert-scout:guess@")
    assert amqp_login(with_cert.replace("&auth_mechanism=external", "")) is False


def test_a_client_certificate_of_another_ca_is_refused(
    cert_robots: dict[str, str], node: LocalNode, tmp_path: Path
) -> None:
    other = TlsFiles.in_folder(tmp_path / "other")
    make_certificates(other)
    forged = ClientFiles.in_folder(other.clients, "cert-scout")
    issue_client_certificate(other, forged, "cert-scout")  # the right name, the wrong CA
    clients = node.tls.clients
    url = (
        cert_robots["cert-scout"]
        .replace(str(clients / "cert-scout.pem"), str(forged.cert))
        .replace(str(clients / "cert-scout.key"), str(forged.key))
    )
    # the broker's alert, or (TLS 1.3: the client's handshake ends before the server checks the
    # certificate) the connection it closes at once
    refused = "TLSV1_ALERT_UNKNOWN_CA|EOF occurred in violation of protocol"
    with pytest.raises(pika.exceptions.AMQPConnectionError, match=refused):
        blocking_connection(url, connection_attempts=1, socket_timeout=5).close()


def test_the_certificate_is_the_identity_a_robot_cannot_act_as_another(
    cert_robots: dict[str, str], node: LocalNode
) -> None:
    """cert-scout's certificate in a URL that names cert-rover logs in as cert-scout: it may
    neither publish on cert-rover's exchange nor sign cert-rover's name on its own messages."""
    clients = node.tls.clients
    url = (
        cert_robots["cert-rover"]
        .replace(str(clients / "cert-rover.pem"), str(clients / "cert-scout.pem"))
        .replace(str(clients / "cert-rover.key"), str(clients / "cert-scout.key"))
    )
    attempts = [
        (events_exchange("cert-rover"), "cert-rover.hazard", "cert-rover", 403),  # not its exchange
        (events_exchange("cert-scout"), "cert-scout.hazard", "cert-rover", 406),  # not its user_id
    ]
    for exchange, key, user_id, refusal in attempts:
        connection = blocking_connection(url, connection_attempts=1, socket_timeout=5)
        try:
            channel = connection.channel()
            channel.confirm_delivery()
            with pytest.raises(pika.exceptions.ChannelClosedByBroker) as refused:
                channel.basic_publish(exchange, key, b"{}", pika.BasicProperties(user_id=user_id))
            assert refused.value.reply_code == refusal
        finally:
            if connection.is_open:
                connection.close()
    ok = blocking_connection(url, connection_attempts=1, socket_timeout=5)
    try:
        channel = ok.channel()
        channel.confirm_delivery()
        properties = pika.BasicProperties(user_id="cert-scout")
        channel.basic_publish(events_exchange("cert-scout"), "cert-scout.hazard", b"{}", properties)
    finally:
        ok.close()


def _keep_aside(url: str, folder: Path) -> str:
    """The URL with its certificate and key copied to ``folder`` (`users add` writes new ones)."""
    query = dict(part.split("=", 1) for part in urlsplit(url).query.split("&"))
    folder.mkdir()
    for field in ("certfile", "keyfile"):
        copy = folder / Path(query[field]).name
        copy.write_bytes(Path(query[field]).read_bytes())
        url = url.replace(query[field], str(copy))
    return url


def test_a_new_certificate_or_a_removal_revokes_the_accounts_earlier_ones(
    node: LocalNode, node_settings: Settings, tmp_path: Path
) -> None:
    """A robot's certificate is lost: `users add --cert --rotate` gives it a new one and the old
    one is refused from its next connection; after `users remove`, an account given that name
    again does not inherit the certificate."""
    first = _keep_aside(_add_cert_robot(node, node_settings, "cert-lost")[0], tmp_path / "first")
    assert can_login(first)
    rotated = _users(node_settings, "add", "cert-lost", "--kind", "explorer", "--cert", "--rotate")
    assert rotated.returncode == 0, rotated.stderr
    assert "revoked 1 earlier certificate(s) of cert-lost" in rotated.stdout
    [second] = [line for line in rotated.stdout.splitlines() if line.startswith("amqp")]
    second = _keep_aside(second, tmp_path / "second")
    log_file = node.status().log_file
    assert log_file is not None
    refused_as_revoked(first, log_file)
    assert can_login(second)

    removed = _users(node_settings, "remove", "cert-lost")
    assert removed.returncode == 0, removed.stderr
    assert "revoked 1 earlier certificate(s) of cert-lost" in removed.stdout
    again = _users(node_settings, "add", "cert-lost", "--kind", "explorer")  # a new robot, a password
    assert again.returncode == 0, again.stderr
    try:
        refused_as_revoked(second, log_file)
    finally:
        assert _users(node_settings, "remove", "cert-lost").returncode == 0


def test_users_add_cert_without_the_cas_key_makes_no_account(
    node: LocalNode, node_settings: Settings
) -> None:
    moved = node.tls.ca_key.with_name("ca.key.away")
    node.tls.ca_key.rename(moved)
    try:
        env = {key: value for key, value in os.environ.items() if not key.startswith("FLEETBUS_")}
        env.update(FLEETBUS_DATA_DIR=str(node_settings.data_dir), COLUMNS="300")
        command = [sys.executable, "-m", "fleetbus", "users", "add", "cert-orphan", "--cert"]
        refused = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
    finally:
        moved.rename(node.tls.ca_key)
    assert refused.returncode == 1 and "CA's key" in refused.stderr
    with _management(node) as api:
        assert api.get_user("cert-orphan") is None


def test_a_node_started_without_certificate_logins_offers_them_after_its_next_start(
    node: LocalNode, node_settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As after an upgrade: the running node was started by a version without EXTERNAL. Passwords
    keep working, `users add --cert` still makes the account and says the node needs a restart;
    after `down` and `up` the certificate logs in."""
    import fleetbus_dev.local_node as local_node

    node.down()
    with monkeypatch.context() as older:
        older.setattr(local_node, "PLUGINS", tuple(p for p in PLUGINS if p != "rabbitmq_auth_mechanism_ssl"))
        older.setattr(local_node, "CERTIFICATE_LOGIN", "")
        info = node.up()
    assert "EXTERNAL" not in (node.base_dir / "rabbitmq.conf").read_text()
    try:
        url, said = _add_cert_robot(node, node_settings, "cert-late")
        assert "the broker refuses the certificate's login" in said and "`fleetbus broker down`" in said
        assert "it has no password" in said and "PRIVATE KEY" not in said
        assert amqp_login(info.amqps_url or "") is True  # passwords as before
        assert "EXTERNAL" in (node.base_dir / "rabbitmq.conf").read_text()  # written for the next start
        with pytest.raises(pika.exceptions.AMQPConnectionError):
            blocking_connection(url, connection_attempts=1, socket_timeout=5)
        node.down()
        node.up()
        blocking_connection(url, connection_attempts=1, socket_timeout=5).close()
    finally:
        assert _users(node_settings, "remove", "cert-late").returncode == 0  # from the registry too


def test_a_configured_broker_that_cannot_be_verified_is_an_error_at_once_not_waited_for(
    node: LocalNode, tmp_path: Path
) -> None:
    other = TlsFiles.in_folder(tmp_path / "other")
    make_certificates(other)
    url = (node.status().amqps_url or "").replace(str(node.tls.ca), str(other.ca))
    started = time.monotonic()
    with pytest.raises(BrokerUnavailable, match=r"cannot be trusted: .*certificate verify failed") as refused:
        wait_for_login(url, "the broker of FLEETBUS_AMQP_URL", wait_s=60)
    assert time.monotonic() - started < 10  # not the 60 s a broker that does not answer is waited for
    assert admin(node)[1] not in str(refused.value)


def test_a_running_node_of_an_older_version_keeps_working_and_gets_tls_at_its_next_start(
    node: LocalNode, caplog: pytest.LogCaptureFixture
) -> None:
    """As after an upgrade: node.json has no TLS ports and the running node listens on none of the
    ones chosen now. `up` returns at once with the plain URLs (robots are handed amqp:// as before)
    and says how to get TLS; the next start listens on the new ports."""
    before = node.status()
    data = json.loads(node.node_file.read_text())
    data["ports"] = {name: port for name, port in data["ports"].items() if name not in TLS_PORT_NAMES}
    node.node_file.write_text(json.dumps(data))
    started = time.monotonic()
    with caplog.at_level(logging.WARNING, logger="fleetbus.broker"):
        info = node.up()
    assert time.monotonic() - started < 10
    assert info.pid == before.pid and info.amqp_url == before.amqp_url
    assert {name: info.ports[name] for name in data["ports"]} == data["ports"]
    assert info.public_url is info.amqps_url is info.management_tls_url is None
    assert any("without its AMQPS and HTTPS listeners" in r.getMessage() for r in caplog.records)
    node.down()
    again = node.up()
    assert again.public_url == f"amqps://127.0.0.1:{info.ports['amqps']}/?cacertfile={node.tls.ca}"
    assert again.amqps_url is not None and amqp_login(again.amqps_url) is True


def _shovel_states(node: LocalNode) -> dict[str, str]:
    listing = node.rabbitmqctl("shovel_status", "--formatter", "json").stdout
    return {shovel["name"]: shovel["state"] for shovel in json.loads(listing or "[]")}


def test_a_shovel_reaches_the_node_over_amqps_only_when_it_can_verify_it(
    node: LocalNode, tmp_path: Path
) -> None:
    """The URL form a site's shovel takes (:func:`shovel_uri`), on RabbitMQ's own Erlang client:
    it moves messages with the right CA and name, and refuses another CA or another name."""
    enabled = node.rabbitmq_plugins("enable", "rabbitmq_shovel", "--online", timeout=120, check=False)
    assert enabled.returncode == 0, enabled.stderr
    info = node.status()
    assert info.amqps_url is not None and info.amqp_url is not None and info.management_url is not None
    other = TlsFiles.in_folder(tmp_path / "other")
    make_certificates(other)
    with pytest.raises(TlsSettingError, match="server_name_indication"):
        shovel_uri(info.amqps_url)  # 127.0.0.1: the Erlang client checks DNS names only
    named = info.amqps_url + "&server_name_indication=localhost"
    shovels = {
        "tls-verified": shovel_uri(named),
        "tls-other-ca": shovel_uri(named.replace(str(node.tls.ca), str(other.ca))),
        "tls-other-name": shovel_uri(info.amqps_url + "&server_name_indication=broker.example"),
    }
    connection = blocking_connection(info.amqp_url)
    channel = connection.channel()
    for name in shovels:
        for queue in (f"{name}.from", f"{name}.to"):
            channel.queue_declare(queue, durable=True)
    connection.close()
    parameters = info.management_url + "api/parameters/shovel/%2F/"
    try:
        for name, uri in shovels.items():
            value = {
                "src-uri": "amqp://",
                "src-queue": f"{name}.from",
                "dest-uri": uri,
                "dest-queue": f"{name}.to",
            }
            answer = httpx.put(parameters + name, json={"value": value}, auth=admin(node), timeout=10)
            assert answer.status_code in (201, 204), answer.text
            _publish(info.amqp_url, f"{name}.from", [b"over the link"])
        wait_for(lambda: _ready(info.amqp_url or "", "tls-verified.to") == 1, 30, "the message over AMQPS")
        assert _shovel_states(node)["tls-verified"] == "running"
        wait_for(
            lambda: (
                "Shovel 'tls-other-ca' failed to connect" in node.node_log.read_text()
                and "Shovel 'tls-other-name' failed to connect" in node.node_log.read_text()
            ),
            30,
            "the two refusals in the node's log",
        )
        logged = node.node_log.read_text()
        assert re.search(r"Shovel 'tls-other-ca' failed to connect .*unknown_ca", logged)
        assert re.search(r"Shovel 'tls-other-name' failed to connect .*hostname_check_failed", logged)
        for name in ("tls-other-ca", "tls-other-name"):
            assert _ready(info.amqp_url, f"{name}.to") == 0 and _ready(info.amqp_url, f"{name}.from") == 1
    finally:
        for name in shovels:
            httpx.delete(parameters + name, auth=admin(node), timeout=10)


def test_down_leaves_no_process(node: LocalNode, node_settings: Settings) -> None:
    info = node.status()
    assert info.pid is not None
    epmds = node.epmd_pids()
    started = time.monotonic()
    node.down()
    took = time.monotonic() - started
    assert not pid_alive(info.pid)
    assert node.pid() is None and not node.status().running
    assert not any(pid_alive(pid) for pid in epmds)
    assert node.epmd_pids() == []
    for name, port in info.ports.items():
        assert pids_listening_on(port) == [], f"something still listens on the {name} port {port}"
    assert took < 60
    started = time.monotonic()
    node.down()  # idempotent, and quick when there is nothing to stop
    assert time.monotonic() - started < 5
    if not docker_engine_answers():
        with pytest.raises(BrokerUnavailable, match="not running"):
            resolve_broker(node_settings.updated(amqp_url=None), start=False)


def test_a_new_node_whose_amqp_port_another_broker_holds_starts_on_new_ports(
    node: LocalNode, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another broker (here the session's node) took the new node's AMQP port between the check
    and the start: it answers the new node's login with a refusal, so the start repairs the login
    on a node that has just died of the taken port. It starts again on new ports, not failing."""
    other = node.status().ports["amqp"]
    fresh = LocalNode(tmp_path / "broker")
    ports = fresh.ports(create=True)
    assert ports is not None
    fresh._save_ports({**ports, "amqp": other})
    monkeypatch.setattr(LocalNode, "_check_ports", lambda self, ports: None)  # the check ran before the take
    try:
        info = fresh.up(timeout=180)
        assert info.ports["amqp"] != other
        assert amqp_login(info.amqp_url or "", timeout=10)
    finally:
        fresh.down()


@pytest.mark.parametrize(
    "taken",
    [
        "management",
        "dist",
        # RabbitMQ 3.10 runs on without a listener whose port was taken, saying so in its own log
        pytest.param("amqps", marks=pytest.mark.rabbitmq_versions),
    ],
)
def test_a_new_node_whose_port_another_process_takes_before_it_listens_starts_on_new_ports(
    taken: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """The race a loaded machine runs: a port checked free is bound by another process before the
    node listens on it. A new node then starts on new ports instead of failing. RabbitMQ reports a
    taken distribution port (Erlang's own) in other words than a taken listener's."""
    fresh = LocalNode(tmp_path / "broker")
    ports = fresh.ports(create=True)
    assert ports is not None
    monkeypatch.setattr(LocalNode, "_check_ports", lambda self, ports: None)  # the check ran before the take
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as taker:
        taker.bind(("127.0.0.1", ports[taken]))
        taker.listen()
        try:
            with caplog.at_level(logging.WARNING, logger="fleetbus_dev.local_node"):
                info = fresh.up(timeout=180)
            assert "was taken before it could listen" in caplog.text, "the first start met the taken port"
            assert info.ports[taken] != ports[taken]
            assert info.ports["epmd"] == ports["epmd"], "a cluster's nodes share epmd's port"
            assert json.loads(fresh.node_file.read_text())["ports"] == info.ports
            assert amqp_login(info.amqp_url or "", timeout=10)
            creds = admin(fresh)
            assert httpx.get(f"{info.management_url}api/overview", auth=creds, timeout=10).status_code == 200
        finally:
            fresh.down()


def test_a_node_whose_unpublished_ports_were_taken_while_it_was_down_moves_them_and_starts(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A restarting node (a cluster's, in a rolling restart) finds its distribution or stream port
    taken by another program: no client was given those, so it moves them and starts; the ports
    clients know (AMQP, AMQPS, the management API) stay where they were."""
    node = LocalNode(tmp_path / "broker")
    before = node.up(timeout=180).ports
    node.down()
    with contextlib.ExitStack() as takers:
        for name in ("dist", "stream"):
            taker = takers.enter_context(socket.socket(socket.AF_INET, socket.SOCK_STREAM))
            taker.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # the node's own may linger
            taker.bind(("127.0.0.1", before[name]))
            taker.listen()
        try:
            with caplog.at_level(logging.WARNING, logger="fleetbus_dev.local_node"):
                after = node.up(timeout=180).ports
            assert "dist, stream moved" in caplog.text
            assert after["dist"] != before["dist"] and after["stream"] != before["stream"]
            published = ("amqp", "amqps", "management", "management_tls", "epmd")
            assert {name: after[name] for name in published} == {name: before[name] for name in published}
            assert amqp_login(node.status().amqp_url or "", timeout=10)
        finally:
            node.down()


def test_a_single_node_and_a_cluster_never_make_the_operators_own_certificates(tmp_path: Path) -> None:
    """Own files (FLEETBUS_TLS_CA/_CERT/_KEY elsewhere than the folder fleetbus makes them in):
    one missing is an error naming it, for `broker up` and `broker up --nodes 3` alike."""
    mine = tmp_path / "mine"
    own = TlsFiles(mine / "ca.pem", mine / "cert.pem", mine / "key.pem", tmp_path / "tls" / "ca.key")
    with pytest.raises(LocalNodeError, match="FLEETBUS_TLS_CA/_CERT/_KEY name are missing") as refused:
        ensure_certificates(own)
    assert str(own.cert) in str(refused.value)
    assert not mine.exists() and not (tmp_path / "tls").exists(), "nothing made"
    ours = TlsFiles.in_folder(tmp_path / "tls")
    ensure_certificates(ours)
    assert ours.server_ready()


def test_a_password_reaches_rabbitmqctl_on_its_standard_input_not_its_command_line(node: LocalNode) -> None:
    """How the start repairs the administrator's login: every local user reads a command line
    (``ps``, /proc), so the password goes on rabbitmqctl's standard input."""
    name, password = f"stdin-{secrets.token_hex(4)}", secrets.token_urlsafe(16)
    node.rabbitmqctl("add_user", name, stdin=password + "\n")
    try:
        checked = node.rabbitmqctl("authenticate_user", name, stdin=password + "\n", check=False)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        wrong = node.rabbitmqctl("authenticate_user", name, stdin="not-it\n", check=False)
        assert wrong.returncode != 0, "the password set is the one read from standard input"
    finally:
        node.rabbitmqctl("delete_user", name, check=False)
