"""The API and TLS: a broker password leaves only over HTTPS, to a client on the API's own machine,
or with FLEETBUS_API_INSECURE_HTTP; the URLs handed out are the broker's public (amqps://) ones;
`fleetbus api --tls` serves HTTPS that clients verify with the CA, and the console's session cookie
is Secure there."""

from __future__ import annotations

import logging
import shutil
import ssl
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from fleetbus.api.console.session import CSRF_COOKIE, CSRF_FIELD, CSRF_HEADER, SESSION_COOKIE
from fleetbus.broker.certificates import TlsFiles, make_certificates
from fleetbus.schemas.roles import UserRole
from tests.api.server import api_process
from tests.api.support import PASSWORD, Api, running_api
from tests.run_tls import run_tls_files
from tests.support import Bus

FAR = "192.0.2.10"  # a client on another machine (TEST-NET-1)


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory: pytest.TempPathFactory) -> TlsFiles:
    """The API's own certificate, signed by the CA of the run's brokers (one CA for a deployment:
    the API's processes verify the broker's management API with the CA they serve)."""
    files = TlsFiles.in_folder(tmp_path_factory.mktemp("tls"))
    run = run_tls_files()
    for made, kept in ((run.ca, files.ca), (run.ca_key, files.ca_key)):
        shutil.copy2(made, kept)
    make_certificates(files)
    return files


def _broker_password(api: Api, name: str) -> str:
    user = api.run(lambda: api.service.accounts.get(name))
    return api.service.accounts.broker_credentials(user).password


def test_plain_http_from_another_machine_gets_the_token_but_not_the_broker_password(
    bus: Bus, caplog: pytest.LogCaptureFixture
) -> None:
    with running_api(bus, client_host=FAR) as api:
        api.user("alice", UserRole.OPERATOR)
        with caplog.at_level(logging.WARNING, logger="fleetbus.api.security"):
            reply = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
        assert reply.status_code == 200, reply.text
        body = reply.json()
        assert body["broker"] is None
        assert "over HTTPS only" in body["broker_withheld"] and FAR in body["broker_withheld"]
        assert "FLEETBUS_API_INSECURE_HTTP" in body["broker_withheld"]
        assert _broker_password(api, "alice") not in reply.text
        assert any("withheld the broker password" in r.getMessage() for r in caplog.records)
        # the token itself works: the web session and the API do not need the broker password
        me = api.client.get("/users/me", headers={"Authorization": f"Bearer {body['access_token']}"})
        assert me.status_code == 200 and me.json()["name"] == "alice"


@pytest.mark.parametrize(
    ("how", "base_url", "insecure"),
    [("HTTPS", "https://testserver", False), ("the insecure setting", "http://testserver", True)],
)
def test_https_or_the_explicit_insecure_setting_hand_the_broker_password_to_another_machine(
    bus: Bus, how: str, base_url: str, insecure: bool
) -> None:
    settings = bus.settings.updated(api_insecure_http=insecure)
    with running_api(bus, settings, client_host=FAR, base_url=base_url) as api:
        api.user("alice", UserRole.OPERATOR)
        reply = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
        assert reply.status_code == 200, reply.text
        assert reply.json()["broker_withheld"] is None
        assert reply.json()["broker"]["password"] == _broker_password(api, "alice")


def test_the_login_hands_out_the_public_amqps_url_with_the_ca(bus: Bus, tls_files: TlsFiles) -> None:
    public = f"amqps://broker.example:5671/?cacertfile={tls_files.ca}"
    with running_api(bus, public_url=public) as api:
        api.user("alice", UserRole.OPERATOR)
        reply = api.client.post("/auth/token", data={"username": "alice", "password": PASSWORD})
        broker = reply.json()["broker"]
        vhost = api.service.vhost
        assert broker["amqp_url"] == (
            f"amqps://alice:{broker['password']}@broker.example:5671/{vhost}?cacertfile={tls_files.ca}"
        )


def test_the_ca_is_served_to_anyone_and_its_absence_explained(bus: Bus, tls_files: TlsFiles) -> None:
    with running_api(bus, bus.settings.updated(tls_dir=tls_files.ca.parent)) as api:
        reply = api.client.get("/ca.pem")
        assert reply.status_code == 200 and reply.text == tls_files.ca.read_text()
    with running_api(bus, bus.settings.updated(tls_dir=bus.settings.data_dir / "none")) as api:
        reply = api.client.get("/ca.pem")
        assert reply.status_code == 404 and "fleetbus certs make" in reply.json()["detail"]


@pytest.fixture
def https_api(bus: Bus, tls_files: TlsFiles) -> Iterator[str]:
    folder = str(tls_files.ca.parent)
    with api_process(bus, "tls-admin", PASSWORD, ca=tls_files.ca, FLEETBUS_TLS_DIR=folder) as (base, _):
        yield base


def test_fleetbus_api_tls_serves_https_verified_with_the_ca_and_a_secure_session_cookie(
    https_api: str, tls_files: TlsFiles
) -> None:
    assert https_api.startswith("https://127.0.0.1:")
    with pytest.raises(httpx.ConnectError, match="CERTIFICATE_VERIFY_FAILED"):
        httpx.get(f"{https_api}/health", timeout=10)  # not a CA the system trusts
    verified = ssl.create_default_context(cafile=str(tls_files.ca))
    with httpx.Client(base_url=https_api, verify=verified, timeout=30) as http:
        assert http.get("/health").status_code == 200
        assert http.get("/ca.pem").text == tls_files.ca.read_text()
        token = http.post("/auth/token", data={"username": "tls-admin", "password": PASSWORD})
        assert token.status_code == 200 and token.json()["broker"]["password"]
        http.get("/console/login")  # the CSRF cookie
        login = http.post(
            "/console/login",
            data={"username": "tls-admin", "password": PASSWORD, CSRF_FIELD: http.cookies[CSRF_COOKIE]},
            follow_redirects=False,
        )
        assert login.status_code == 303, login.text
        [session] = [c for c in login.headers.get_list("set-cookie") if c.startswith(f"{SESSION_COOKIE}=")]
        assert "; secure" in session.lower() and "httponly" in session.lower()


def test_api_tls_without_a_certificate_says_what_to_do(bus: Bus, tmp_path: Path) -> None:
    env = {**bus.worker_env(), "FLEETBUS_TLS_DIR": str(tmp_path / "none")}
    result = subprocess.run(
        [sys.executable, "-m", "fleetbus", "api", "--tls", "--port", "1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1 and "fleetbus certs make" in result.stderr


def test_the_consoles_broker_password_reset_is_refused_over_plain_http_before_the_password_changes(
    bus: Bus,
) -> None:
    with running_api(bus, client_host=FAR) as api:
        api.user("admin1", UserRole.ADMIN)
        api.user("alice", UserRole.OPERATOR)
        before = _broker_password(api, "alice")
        api.client.get("/console/login")  # the CSRF cookie
        api.client.cookies.set(SESSION_COOKIE, api.session("admin1"))
        reply = api.client.post(
            "/console/accounts/alice/broker-password", headers={CSRF_HEADER: api.client.cookies[CSRF_COOKIE]}
        )
        assert reply.status_code == 403
        assert "over HTTPS only" in reply.text
        assert _broker_password(api, "alice") == before
