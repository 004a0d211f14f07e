"""A user made or removed through the API revokes the client certificates fleetbus's CA signed for
that name, as `fleetbus users add` and `remove` do; when they cannot be revoked (the CA's key is not
here) nothing changes. The broker's refusal of a revoked certificate is in ``tests/test_revocation.py``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from fleetbus.broker.certificates import ClientFiles, TlsFiles, issue_client_certificate, make_certificates
from fleetbus.broker.revocation import issued_certificates, read_crl
from fleetbus.schemas.roles import UserRole
from tests.api.support import PASSWORD, Api, running_api
from tests.support import Bus

ROBOT = {"name": "scout1", "password": PASSWORD, "role": "robot", "kind": "explorer"}


@pytest.fixture
def ca(tmp_path: Path) -> TlsFiles:
    """A CA of the test's own (the run's CA signs for every test at once)."""
    files = TlsFiles.in_folder(tmp_path / "tls")
    make_certificates(files)
    return files


@pytest.fixture
def api(bus: Bus, ca: TlsFiles) -> Iterator[Api]:
    settings = bus.settings.updated(tls_dir=ca.ca_key.parent, tls_ca=None, tls_cert=None, tls_key=None)
    with running_api(bus, settings) as running:
        running.user("admin1", UserRole.ADMIN)
        yield running


def _certificate(ca: TlsFiles, folder: Path, name: str) -> int:
    issue_client_certificate(ca, ClientFiles.in_folder(folder, name), name)
    return issued_certificates(ca, name)[-1].serial


def _revoked(ca: TlsFiles) -> set[int]:
    crl = read_crl(ca)
    return set(crl.revoked) if crl is not None else set()


def test_making_and_removing_a_user_revokes_the_certificates_signed_for_its_name(
    api: Api, ca: TlsFiles, tmp_path: Path
) -> None:
    earlier = _certificate(ca, tmp_path / "out", "scout1")
    other = _certificate(ca, tmp_path / "out", "scout2")
    reply = api.call("admin1", "POST", "/users", json=ROBOT)
    assert reply.status_code == 201, reply.text
    assert _revoked(ca) == {earlier}, "the new account does not inherit the name's certificate"

    later = _certificate(ca, tmp_path / "again", "scout1")
    assert api.call("admin1", "DELETE", "/users/scout1").status_code == 204
    assert _revoked(ca) == {earlier, later} and other not in _revoked(ca)


def test_without_the_cas_key_a_name_with_certificates_is_neither_made_nor_removed(
    api: Api, ca: TlsFiles, tmp_path: Path
) -> None:
    api.user("scout2", UserRole.ROBOT)
    for name in ("scout1", "scout2"):
        _certificate(ca, tmp_path / "out", name)
    ca.ca_key.rename(ca.ca_key.with_name("ca.key.away"))

    made = api.call("admin1", "POST", "/users", json=ROBOT)
    assert made.status_code == 503 and "needs the CA's key" in made.json()["detail"], made.text
    assert api.bus.api.get_user("scout1") is None, "no broker account"
    removed = api.call("admin1", "DELETE", "/users/scout2")
    assert removed.status_code == 503 and "needs the CA's key" in removed.json()["detail"], removed.text
    assert api.bus.api.get_user("scout2") is not None, "the broker account is still there"
    names = [u.name for u in api.run(api.service.repositories.users.users)]
    assert names == ["admin1", "scout2"] and _revoked(ca) == set()
