"""Whether a broker answers: an AMQP login, the management API, a private file for credentials.

Used by every command that waits for a configured broker (:mod:`fleetbus.broker.endpoint`) and by
the development tooling that starts one (:mod:`fleetbus_dev`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import ssl
from collections.abc import Iterator
from pathlib import Path


def write_private_file(path: Path, text: str, mode: int = 0o600) -> None:
    """Write ``text`` to ``path`` readable by its owner only, atomically (a password, a cookie)."""
    tmp = path.with_name(path.name + ".tmp")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "w") as handle:
        handle.write(text)
    os.chmod(tmp, mode)
    os.replace(tmp, path)


@contextlib.contextmanager
def _quiet_pika() -> Iterator[None]:
    """pika logs every refused connection attempt at ERROR; a readiness poll expects refusals."""
    logger = logging.getLogger("pika")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)


class NoAnswer(Exception):
    """Nothing usable answers at an AMQP URL (refused, timed out, still starting); the message says what."""


class NotVerified(Exception):
    """The broker's TLS certificate or host name did not verify, or the URL's TLS files are
    unusable: waiting does not help. The message says why."""


def _innermost(error: BaseException) -> BaseException:
    """The innermost cause of a failed connection (pika wraps it in one or two exceptions)."""
    while True:
        inner = getattr(error, "exception", None) or (error.args[-1] if error.args else None)
        if not isinstance(inner, BaseException):
            return error
        error = inner


def _reason(error: BaseException) -> str:
    error = _innermost(error)
    return f"{type(error).__name__}: {error}" if str(error) else type(error).__name__


def check_amqp_login(url: str, timeout: float = 3.0) -> bool:
    """Try an AMQP login: True when it works, False when the credentials are refused; raise
    :class:`NoAnswer` when nothing usable answers (connection refused, timeout, broker starting),
    :class:`NotVerified` when TLS verification failed."""
    import pika
    import pika.exceptions

    from fleetbus.publishers.errors import CONNECTION_FAILED
    from fleetbus.publishers.tls import TlsSettingError, pika_parameter_list

    try:
        parameters = pika_parameter_list(
            url,
            connection_attempts=1,
            retry_delay=0,
            socket_timeout=timeout,
            stack_timeout=timeout,
            blocked_connection_timeout=timeout,
        )
    except TlsSettingError as error:
        raise NotVerified(str(error)) from None
    with _quiet_pika():
        try:
            pika.BlockingConnection(parameters).close()
        except pika.exceptions.ProbableAuthenticationError:
            return False
        except pika.exceptions.ProbableAccessDeniedError:
            return True  # the login worked; only the virtual host is refused
        except (pika.exceptions.AMQPError, *CONNECTION_FAILED, OSError) as error:
            if isinstance(_innermost(error), ssl.SSLCertVerificationError):
                raise NotVerified(_reason(error)) from None
            raise NoAnswer(_reason(error)) from None
    return True


def amqp_login(url: str, timeout: float = 3.0) -> bool | None:
    """:func:`check_amqp_login`, with None when nothing usable answers (or cannot be verified)."""
    try:
        return check_amqp_login(url, timeout)
    except (NoAnswer, NotVerified):
        return None


def management_answers(management_url: str, username: str, password: str, timeout: float = 3.0) -> bool:
    """Whether ``GET /api/overview`` answers 200 with these credentials."""
    import httpx

    from fleetbus.broker.management import verification

    try:
        response = httpx.get(
            management_url.rstrip("/") + "/api/overview",
            auth=(username, password),
            timeout=timeout,
            verify=verification(management_url),
        )
    except httpx.HTTPError:
        return False
    return response.status_code == 200
