"""The broker probe's answer when a broker accepts the connection but does not finish the handshake."""

from __future__ import annotations

import socket
import time

import pika
import pytest

from fleetbus.broker.probe import NoAnswer, check_amqp_login
from fleetbus.publishers.errors import CONNECTION_FAILED


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


def test_every_way_a_connection_fails_to_open_is_among_connection_failed() -> None:
    """What the robot client, the dead-letter requeue and the CLI catch around opening a connection:
    a refused port, and a broker that never finishes the handshake (pika's default of one attempt
    raises the connector's own error then, which is no AMQPError)."""
    with socket.socket() as silent, socket.socket() as closed:
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        closed.bind(("127.0.0.1", 0))  # bound, never listening: the connection is refused
        for sock in (silent, closed):
            port = sock.getsockname()[1]
            parameters = pika.ConnectionParameters(
                "127.0.0.1", port, connection_attempts=1, socket_timeout=0.5, stack_timeout=0.5
            )
            with pytest.raises(CONNECTION_FAILED):
                pika.BlockingConnection(parameters)
