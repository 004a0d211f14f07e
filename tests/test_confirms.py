"""Pipelined publisher confirms on the real broker: the waits end when the broker answers."""

from __future__ import annotations

import time

import pika
import pytest

from fleetbus.publishers import confirms
from fleetbus.publishers.confirms import Outgoing, PipelinedConfirms
from fleetbus.publishers.tls import blocking_connection
from tests.support import Bus

SLICE = 60.0


def test_turning_confirms_on_and_a_confirm_end_the_wait_not_its_time_slice(
    bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    """pika's blocking loop does not return for frames of the channel underneath its facade: each
    wait would last its whole slice (50 ms: every robot's connect took 54 ms) unless woken."""
    monkeypatch.setattr(confirms, "_SLICE", SLICE)
    connection = blocking_connection(bus.admin_url)
    try:
        channel = connection.channel()
        channel.queue_declare("test.confirms", durable=True)
        started = time.monotonic()
        pipelined = PipelinedConfirms(connection, channel, timeout=2 * SLICE)
        selected = time.monotonic()
        properties = pika.BasicProperties(delivery_mode=2, message_id="m1")
        pipelined.publish([Outgoing("", "test.confirms", b"{}", properties)], 2 * SLICE)
        confirmed = time.monotonic()
    finally:
        connection.close()
    assert selected - started < SLICE / 2, "confirm.select-ok woke the wait"
    assert confirmed - selected < SLICE / 2, "the confirm woke the wait"
