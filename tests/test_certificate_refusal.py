"""What a robot is told when the broker ends its certificate login's TLS handshake
(:mod:`fleetbus.publishers.handshake`); the real broker's refusal is in ``test_revocation.py``."""

from __future__ import annotations

import ssl

import pika.exceptions
import pytest
from pika.adapters.utils.connection_workflow import AMQPConnectorSocketConnectError

from fleetbus.publishers.handshake import broker_unverified, certificate_refusal


def _wrapped(inner: BaseException) -> BaseException:
    """As pika raises it: the socket's error an argument of its own errors."""
    return pika.exceptions.AMQPConnectionError(AMQPConnectorSocketConnectError(inner))


@pytest.mark.parametrize(
    ("error", "said"),
    [
        (
            _wrapped(
                ssl.SSLError(1, "[SSL: SSLV3_ALERT_CERTIFICATE_REVOKED] sslv3 alert certificate revoked")
            ),
            "is revoked",
        ),
        (
            _wrapped(
                ssl.SSLError(1, "[SSL: SSLV3_ALERT_CERTIFICATE_EXPIRED] sslv3 alert certificate expired")
            ),
            "has expired",
        ),
        (
            _wrapped(ssl.SSLError(1, "[SSL: TLSV1_ALERT_UNKNOWN_CA] tlsv1 alert unknown ca")),
            "does not know the CA",
        ),
        (
            pika.exceptions.AMQPConnectionError(
                pika.exceptions.StreamLostError(
                    "Stream connection lost: "
                    "SSLEOFError(8, 'EOF occurred in violation of protocol (_ssl.c:2427)')"
                )
            ),
            "revoked, expired or not signed by the broker's CA",
        ),
        (
            _wrapped(ConnectionResetError(104, "Connection reset by peer")),
            "the broker's log names the reason",
        ),
    ],
)
def test_a_handshake_the_broker_ended_is_explained(error: BaseException, said: str) -> None:
    explanation = certificate_refusal(error)
    assert explanation is not None and said in explanation


@pytest.mark.parametrize(
    "error",
    [
        _wrapped(ConnectionRefusedError(111, "Connection refused")),  # nothing listens: not a refusal
        pika.exceptions.ProbableAccessDeniedError("ConnectionClosedByBroker: (403) ACCESS_REFUSED"),
        _wrapped(ssl.SSLCertVerificationError(1, "certificate verify failed: unable to get local issuer")),
        TimeoutError("timed out"),
    ],
)
def test_other_failures_get_no_certificate_explanation(error: BaseException) -> None:
    assert certificate_refusal(error) is None


def test_only_a_broker_certificate_the_robot_cannot_verify_ends_its_wait_to_connect() -> None:
    unverified = ssl.SSLCertVerificationError(1, "certificate verify failed: unable to get local issuer")
    assert broker_unverified(_wrapped(unverified))
    revoked = ssl.SSLError(1, "[SSL: SSLV3_ALERT_CERTIFICATE_REVOKED] sslv3 alert certificate revoked")
    for other in (_wrapped(revoked), _wrapped(ConnectionRefusedError(111, "Connection refused"))):
        assert not broker_unverified(other)
