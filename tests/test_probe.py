"""The broker probe's answer when a broker accepts the connection but does not finish the handshake."""

from __future__ import annotations

import socket
import time

import pytest

from fleetbus.broker.probe import NoAnswer, check_amqp_login


def test_a_handshake_that_never_ends_is_no_answer_to_retry_not_a_crash() -> None:
    """A loaded broker can take longer than the probe's timeout to answer the AMQP handshake; pika
    then raises its connector's timeout (no AMQPError), which must be retried as no answer."""
    with socket.socket() as silent:  # accepts (the kernel's backlog) and never speaks AMQP
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        port = silent.getsockname()[1]
        started = time.monotonic()
        with pytest.raises(NoAnswer, match="Timeout"):
            check_amqp_login(f"amqp://someone:secret@127.0.0.1:{port}/", timeout=0.5)
        assert time.monotonic() - started < 10
