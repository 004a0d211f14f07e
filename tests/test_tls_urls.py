"""Broker URLs made into connection parameters (:mod:`fleetbus.broker.tls`): amqp:// unchanged,
amqps:// verified by default with RabbitMQ's own URI query parameters, verify_none the only way out."""

from __future__ import annotations

import ssl
from pathlib import Path
from urllib.parse import urlsplit

import pika.credentials
import pytest

from fleetbus.broker.certificates import ClientFiles, TlsFiles, issue_client_certificate, make_certificates
from fleetbus.broker.tls import aio_pika_arguments, shovel_uri
from fleetbus.publishers.tls import TlsSettingError, pika_parameters, split_tls, with_client_certificate


@pytest.fixture(scope="module")
def ca(tmp_path_factory: pytest.TempPathFactory) -> Path:
    files = TlsFiles.in_folder(tmp_path_factory.mktemp("tls"))
    make_certificates(files)
    return files.ca


def test_an_amqp_url_is_passed_through_as_before() -> None:
    url = "amqp://robot:secret@127.0.0.1:5672/fleet?heartbeat=7"
    assert split_tls(url) == (url, None)
    parameters = pika_parameters(url)
    assert parameters.ssl_options is None
    assert (parameters.host, parameters.port, parameters.virtual_host, parameters.heartbeat) == (
        "127.0.0.1",
        5672,
        "fleet",
        7,
    )
    assert aio_pika_arguments(url) == (url, {})


def test_amqps_verifies_the_certificate_and_the_host_name_by_default(ca: Path) -> None:
    url = f"amqps://robot:secret@broker.example:5671/?cacertfile={ca}&heartbeat=9"
    plain, options = split_tls(url)
    assert plain == "amqps://robot:secret@broker.example:5671/?heartbeat=9"  # pika refuses unknown keys
    assert options is not None and options.verify and options.server_name == "broker.example"
    parameters = pika_parameters(url)
    assert parameters.heartbeat == 9
    assert parameters.ssl_options is not None
    assert parameters.ssl_options.server_hostname == "broker.example"
    context = parameters.ssl_options.context
    assert context.verify_mode is ssl.CERT_REQUIRED and context.check_hostname
    assert len(context.get_ca_certs()) == 1  # the URL's CA, not the system's
    _, arguments = aio_pika_arguments(url)
    assert arguments["ssl_context"].verify_mode is ssl.CERT_REQUIRED


@pytest.mark.parametrize(
    ("url", "port"),
    [
        ("amqps://robot:s%40cret@broker.example/fleet", 5671),
        ("amqps://robot:s%40cret@[::1]:5999/fleet", 5999),
    ],
)
def test_amqps_keeps_its_port_host_account_and_virtual_host(ca: Path, url: str, port: int) -> None:
    parameters = pika_parameters(f"{url}?cacertfile={ca}&heartbeat=9")
    host = urlsplit(url).hostname
    assert (parameters.host, parameters.port, parameters.virtual_host, parameters.heartbeat) == (
        host,
        port,
        "fleet",
        9,
    )
    assert (parameters.credentials.username, parameters.credentials.password) == ("robot", "s@cret")
    assert len(parameters.ssl_options.context.get_ca_certs()) == 1


def test_without_cacertfile_the_system_trust_store_is_used() -> None:
    context = pika_parameters("amqps://robot:secret@broker.example/").ssl_options.context
    assert context.verify_mode is ssl.CERT_REQUIRED and context.check_hostname


def test_verify_none_is_the_explicit_opt_out(ca: Path) -> None:
    context = pika_parameters(f"amqps://r:s@broker.example/?cacertfile={ca}&verify=verify_none").ssl_options
    assert context.context.verify_mode is ssl.CERT_NONE and not context.context.check_hostname


def test_server_name_indication_names_the_host_to_check(ca: Path) -> None:
    url = f"amqps://r:s@10.0.0.5:5671/?cacertfile={ca}&server_name_indication=broker.example"
    assert pika_parameters(url).ssl_options.server_hostname == "broker.example"


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("amqp://r:s@host/?cacertfile=/ca.pem", "apply to amqps:// only"),
        ("amqps://r:s@host/?verify=maybe", "verify_peer or verify_none"),
        ("amqps://r:s@host/?cacertfile=/no/such/ca.pem", "cannot load the TLS files"),
    ],
)
def test_wrong_tls_parameters_are_refused_saying_why(url: str, said: str) -> None:
    with pytest.raises(TlsSettingError, match=said):
        pika_parameters(url)


def test_a_shovel_uri_spells_out_verification_and_the_default_virtual_host(ca: Path) -> None:
    url = f"amqps://site:pw@central.example:5671/?cacertfile={ca}&heartbeat=10"
    assert shovel_uri(url) == (
        f"amqps://site:pw@central.example:5671/%2F?heartbeat=10&cacertfile={ca}"
        "&verify=verify_peer&server_name_indication=central.example"
    )
    assert shovel_uri("amqp://site:pw@central.example/fleet") == "amqp://site:pw@central.example/fleet"
    with pytest.raises(TlsSettingError, match="needs cacertfile"):
        shovel_uri("amqps://site:pw@central.example/")


@pytest.fixture(scope="module")
def robot_cert(ca: Path) -> ClientFiles:
    files = TlsFiles.in_folder(ca.parent)
    client = ClientFiles.in_folder(files.clients, "scout-1")
    issue_client_certificate(files, client, "scout-1")
    return client


def test_auth_mechanism_external_logs_in_with_the_client_certificate(
    ca: Path, robot_cert: ClientFiles
) -> None:
    url = (
        f"amqps://scout-1@broker.example:5671/?cacertfile={ca}&certfile={robot_cert.cert}"
        f"&keyfile={robot_cert.key}&auth_mechanism=external&heartbeat=9"
    )
    plain, options = split_tls(url)
    assert plain == "amqps://scout-1@broker.example:5671/?heartbeat=9"  # pika refuses unknown keys
    assert options is not None and options.external and options.certfile == str(robot_cert.cert)
    parameters = pika_parameters(url)
    assert isinstance(parameters.credentials, pika.credentials.ExternalCredentials)
    assert parameters.heartbeat == 9
    aio_url, arguments = aio_pika_arguments(url)
    assert aio_url == "amqps://scout-1@broker.example:5671/?heartbeat=9&auth=external"  # aiormq's name
    assert "ssl_context" in arguments
    assert shovel_uri(url).endswith("&auth_mechanism=external")
    password = pika_parameters(url.replace("&auth_mechanism=external", "").replace("scout-1@", "scout-1:pw@"))
    assert isinstance(password.credentials, pika.credentials.PlainCredentials)


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("amqp://r@host/?auth_mechanism=external", "amqps:// only"),
        ("amqps://r@host/?auth_mechanism=external", "needs the client certificate"),
        ("amqps://r:s@host/?auth_mechanism=kerberos", "use plain or external"),
    ],
)
def test_a_certificate_login_without_tls_or_a_certificate_is_refused_saying_why(url: str, said: str) -> None:
    with pytest.raises(TlsSettingError, match=said):
        pika_parameters(url)


def test_with_client_certificate_drops_the_password_and_names_the_files() -> None:
    url = "amqps://scout-1:secret@a.example:5671,b.example:5671/fleet?cacertfile=/ca.pem"
    assert with_client_certificate(url, "/c/scout-1.pem", "/c/scout-1.key") == (
        "amqps://scout-1@a.example:5671,b.example:5671/fleet?cacertfile=/ca.pem&certfile=/c/scout-1.pem"
        "&keyfile=/c/scout-1.key&auth_mechanism=external"
    )
    with pytest.raises(TlsSettingError, match="amqps://"):
        with_client_certificate("amqp://scout-1:pw@host/", "/c.pem", "/c.key")
