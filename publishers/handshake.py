"""Why the broker most likely ended a robot's TLS handshake, said in words.

A broker that refuses a client certificate (revoked, expired, signed by another CA) ends the
handshake with an alert. Under TLS 1.3 the client has often finished its side by then and sees
only the connection closing ("EOF occurred in violation of protocol"), and pika wraps that in
errors of its own: a robot's log would say nothing about its certificate. Base install: the
standard library only.
"""

from __future__ import annotations

import ssl
from collections.abc import Iterator

#: Alerts that name the reason, as OpenSSL words them (lower case), and what a robot is told.
_ALERTS = (
    ("alert certificate revoked", "the broker says this robot's client certificate is revoked"),
    ("alert certificate expired", "the broker says this robot's client certificate has expired"),
    ("alert unknown ca", "the broker does not know the CA that signed this robot's client certificate"),
)
#: What a handshake ended without a reason looks like from the robot.
_ENDED = (
    "eof occurred in violation of protocol",
    "unexpected eof",
    "transport indicated eof",
    "connection reset",
    "alert bad certificate",
    "alert certificate unknown",
    "alert certificate required",
)
_UNSAID = (
    "the broker ended the TLS handshake: with a client certificate this most often means it is "
    "revoked, expired or not signed by the broker's CA (the broker's log names the reason)"
)


def certificate_refusal(error: BaseException) -> str | None:
    """What ``error``, raised while a robot logged in with a client certificate, most likely
    means; None when it does not look like a handshake the broker ended."""
    text = _described(error).lower()
    for alert, meaning in _ALERTS:
        if alert in text:
            return meaning
    if any(sign in text for sign in _ENDED):
        return _UNSAID
    return None


def broker_unverified(error: BaseException) -> bool:
    """Whether ``error`` says the robot could not verify the broker's certificate (another CA, a
    name the certificate does not carry): trying again will not change that."""
    return any(isinstance(each, ssl.SSLCertVerificationError) for each in _wrapped(error))


def _described(error: BaseException) -> str:
    return " ".join(repr(each) for each in _wrapped(error))


def _wrapped(error: BaseException, depth: int = 0) -> Iterator[BaseException]:
    """``error`` and everything it wraps: its cause, its context, and what pika passes the
    socket's error on in (an argument, or a connector error's ``exception``)."""
    if depth > 5:
        return
    yield error
    carried = getattr(error, "exception", None)
    inner = [error.__cause__, error.__context__, carried, *error.args]
    inner = [each for each in inner if isinstance(each, BaseException)]
    for each in inner:
        if each is not error:
            yield from _wrapped(each, depth + 1)
