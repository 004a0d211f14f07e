"""The broker's certificate on the dashboard: read from the broker as a client meets it, and shown
with a warning ahead of its expiry (every robot's TLS connection fails once it has expired)."""

from __future__ import annotations

import re
from datetime import datetime, timedelta, timezone
from urllib.parse import urlsplit, urlunsplit

import pytest

from fleetbus.api.console.broker_health import BrokerHealth, CertificateCheck, check_certificate
from fleetbus.api.console.templating import fragment
from fleetbus.broker.served_certificate import ServedCertificate
from tests.api.server import free_port
from tests.run_tls import BROKER_TLS
from tests.support import Bus


@pytest.mark.skipif(not BROKER_TLS, reason="the suite's broker is reached over plain AMQP")
def test_the_certificate_the_node_presents_is_read_and_verified(bus: Bus) -> None:
    check = check_certificate([bus.admin_url], warn_days=30)
    assert check.problem is None and check.certificate is not None
    assert check.certificate.address == f"127.0.0.1:{urlsplit(bus.admin_url).port}"
    assert check.state == "ok" and 360 < (check.days_left or 0) <= 366, "fleetbus signs for 366 days"


def test_a_plain_address_has_no_certificate_and_a_silent_one_is_a_problem(bus: Bus) -> None:
    parts = urlsplit(bus.admin_url)
    plain = urlunsplit(("amqp", parts.netloc, parts.path, "", ""))
    assert check_certificate([plain], warn_days=30).plain
    nobody = urlunsplit(("amqps", f"127.0.0.1:{free_port()}", "/", parts.query, ""))
    check = check_certificate([nobody], warn_days=30)
    assert check.state == "unknown" and check.problem is not None and "could not be read" in check.problem


def _line(days: float | None, problem: str | None = None) -> str:
    now = datetime.now(timezone.utc)
    served = None
    if days is not None:
        served = ServedCertificate("broker.lan:5671", "CN=broker.lan", now + timedelta(days=days))
    check = CertificateCheck(now, 30, certificate=served, problem=problem)
    panel = fragment("dashboard/broker.html", health=BrokerHealth(problem=None, certificate=check))
    [line] = re.findall(r'<p id="broker-tls".*?</p>', panel, re.DOTALL)
    return " ".join(line.split())


def test_the_dashboard_warns_ahead_of_the_expiry_and_says_what_to_do() -> None:
    fine = _line(400.5)
    assert "expires on" in fine and "in 400 days" in fine and 'role="alert"' not in fine
    soon = _line(10.2)
    assert "in 10 days: replace it before then" in soon and 'class="certificate warn"' in soon
    assert 'role="alert"' in soon
    gone = _line(-1)
    assert "expired on" in gone and "robots cannot connect" in gone and 'class="certificate bad"' in gone
    unread = _line(None, problem="could not be read: [SSL: CERTIFICATE_VERIFY_FAILED]")
    assert "could not be read: [SSL: CERTIFICATE_VERIFY_FAILED]" in unread and "certificate bad" in unread
