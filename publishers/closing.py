"""Closing a broker connection of the robot's without waiting for a broker that does not answer.

A graceful close waits for the broker's answer, which never comes when the network went silent
(no reset): pika would wait for the heartbeat to time out, tens of seconds.
"""

from __future__ import annotations

import pika
import pika.exceptions

#: How long (seconds) closing a connection waits for the broker's answer before dropping the
#: socket: a network gone silent (no reset) never answers, and pika's close would wait for the
#: heartbeat to time out (tens of seconds).
CLOSE_WAIT_S = 1.0


def close_quietly(connection: pika.BlockingConnection) -> None:
    """Close ``connection`` from its own thread (or once that thread is gone), broken or not."""
    if connection.is_open:
        # on the I/O loop close() runs (BlockingConnection.call_later's callbacks wait for the
        # next process_data_events, which close() never calls)
        connection._impl._adapter_call_later(CLOSE_WAIT_S, lambda: _give_up_closing(connection))
        try:
            connection.close()
        except pika.exceptions.AMQPError:
            pass  # already broken


def _give_up_closing(connection: pika.BlockingConnection) -> None:
    """End the connection's stream with an error, as pika does when it loses one: the close was
    not answered in time. (Aborting the transport instead, mid-close, fails pika's own checks.)"""
    impl = connection._impl
    if not impl.is_closed:
        impl._terminate_stream(
            pika.exceptions.StreamLostError(f"the broker did not answer the close within {CLOSE_WAIT_S:g} s")
        )
