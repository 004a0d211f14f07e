"""Requeue or discard one dead letter, named by its :func:`~fleetbus.broker.dead_letter_queue.letter_id`.

Both take the queue's messages one by one (``basic.get``, unacked) until the named one, act on
it, and close the channel: every other message goes back to its place, in its order. A letter
taken meanwhile by another operator is unacked on their channel, so it cannot be taken twice.
A letter that is not in the queue any more (requeued, discarded, dropped from a full queue)
raises :class:`DeadLetterGone` and nothing changes.

Requeue publishes the message again to its original exchange and routing key **as the account
that first sent it** (its ``user_id``), with publisher confirms and ``mandatory``, and only then
removes it from the queue. The broker checks that account's permissions and its validated
user id as it did the first time: requeue never speaks for anyone (no ``impersonator`` tag), and
a sender that was disabled or removed cannot be requeued. A process that dies between the
confirm and the removal leaves the letter listed as well as requeued; the workers store events
idempotently by robot and sequence, so requeueing it twice stores it once.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel

from fleetbus.broker.dead_letter_queue import DELIVERY_HEADERS, DeadLetter, describe, letter_id
from fleetbus.publishers.confirms import SERVICE_CONFIRM_TIMEOUT_S, Outcome, Outgoing, PipelinedConfirms
from fleetbus.publishers.errors import CONNECTION_FAILED, PublisherError
from fleetbus.publishers.tls import blocking_connection, pika_parameter_list
from fleetbus.schemas.routing import DEAD_LETTER_QUEUE

#: What the broker (or an earlier fleetbus) wrote on the letter about its refusal: not part of
#: the message sent again, which the broker will describe afresh if it is refused again.
DEATH_HEADERS = frozenset(
    {
        "x-death",
        "x-first-death-queue",
        "x-first-death-reason",
        "x-first-death-exchange",
        "x-last-death-queue",
        "x-last-death-reason",
        "x-last-death-exchange",
        "x-fleetbus-reason",
        "x-fleetbus-detail",
        "x-rejected-at",
        "x-original-exchange",
        "x-original-routing-key",
        "x-original-user-id",
    }
)

#: The sender's AMQP URL (its own login) for a user id; raises :class:`RequeueRefused` when
#: there is none to be had.
SenderUrl = Callable[[str], str]


class DeadLetterGone(LookupError):
    """The letter is not in the dead-letter queue (any more); nothing was changed."""


class RequeueRefused(RuntimeError):
    """The message could not be published again as its sender; it stays a dead letter."""


class RemovalUnconfirmed(RuntimeError):
    """Published again, but the dead-letter queue did not confirm the letter's removal."""


@dataclass(frozen=True)
class _Held:
    channel: BlockingChannel
    delivery_tag: int
    letter: DeadLetter
    properties: pika.BasicProperties


def _gone(wanted: str) -> DeadLetterGone:
    return DeadLetterGone(
        f"dead letter {wanted} is not in the queue: it was requeued, discarded or dropped "
        "meanwhile, or another operator is handling it; nothing was changed"
    )


#: How long an action looks for a letter that is not in the queue: another reader (a listing
#: of the console's, ``fleetbus dlq``) holds the letters it peeks for a moment, unacked.
HELD_ELSEWHERE_S = 5.0


@contextmanager
def _holding(amqp_url: str, wanted: str, patience: float = HELD_ELSEWHERE_S) -> Iterator[_Held]:
    """The named letter, taken from the queue and held unacked on a channel of the administrator's;
    leaving puts every message not acked back in its place. A letter not found is looked for
    again, until ``patience`` runs out, while another reader may hold it."""
    connection = blocking_connection(amqp_url)
    try:
        deadline = time.monotonic() + patience
        while True:
            channel = connection.channel()
            held = _find(channel, wanted)
            if held is not None:
                yield held
                return
            channel.close()  # returns what it took, before another look
            if time.monotonic() >= deadline:
                raise _gone(wanted)
            time.sleep(0.2)  # a reader's hold lasts as long as its listing takes
    finally:
        if connection.is_open:
            connection.close()


def _find(channel: BlockingChannel, wanted: str) -> _Held | None:
    """Take messages from the queue (unacked) until the named letter; None if it is not there."""
    available = channel.queue_declare(DEAD_LETTER_QUEUE, passive=True).method.message_count
    for _ in range(available):
        method, properties, body = channel.basic_get(DEAD_LETTER_QUEUE, auto_ack=False)
        if method is None:
            return None
        if letter_id(properties, body) == wanted:
            letter = describe(properties, body, method.routing_key)
            return _Held(channel, method.delivery_tag, letter, properties)
    return None


def _acked(held: _Held) -> None:
    """Remove the held letter; the channel's close answers only once the broker applied the ack."""
    held.channel.basic_ack(held.delivery_tag)
    held.channel.close()


def discard_dead_letter(amqp_url: str, wanted: str, patience: float = HELD_ELSEWHERE_S) -> DeadLetter:
    """Remove exactly the named letter from the queue (as administrator, ``amqp_url``)."""
    with _holding(amqp_url, wanted, patience) as held:
        _acked(held)
    return held.letter


def requeue_dead_letter(
    amqp_url: str, wanted: str, sender_url: SenderUrl, patience: float = HELD_ELSEWHERE_S
) -> DeadLetter:
    """Publish the named letter again as its sender (``sender_url(user_id)``), to its original
    exchange and routing key, confirmed; then remove it from the queue."""
    with _holding(amqp_url, wanted, patience) as held:
        letter = held.letter
        if not letter.user_id:
            raise RequeueRefused(
                f"dead letter {wanted} names no sender (no user_id): it cannot be published as anyone"
            )
        if letter.exchange.partition(".")[0] != letter.user_id:
            raise RequeueRefused(
                f"dead letter {wanted} went to exchange {letter.exchange!r}, not one of its sender "
                f"{letter.user_id}'s: it is published again only as its sender, to its own exchange"
            )
        _publish_as(sender_url(letter.user_id), letter, held.properties)
        try:
            _acked(held)
        except pika.exceptions.AMQPError as error:
            raise RemovalUnconfirmed(
                f"dead letter {wanted} was published again as {letter.user_id}, but the queue did "
                f"not confirm its removal ({error!r}): if it is still listed, discard it"
            ) from error
    return letter


def _raise_unless_taken(outcome: Outcome, sender: str) -> None:
    if outcome.returned:
        raise RequeueRefused(f"published as {sender}, it reached no queue; it stays a dead letter")
    if outcome.nacked:
        raise RequeueRefused(f"the broker did not take it as {sender}; it stays a dead letter")


def _publish_as(url: str, letter: DeadLetter, properties: pika.BasicProperties) -> None:
    again = copy.copy(properties)
    dropped = DEATH_HEADERS | DELIVERY_HEADERS
    again.headers = {k: v for k, v in (properties.headers or {}).items() if k not in dropped}
    again.user_id = letter.user_id
    parameters = pika_parameter_list(url, connection_attempts=1)
    sender = f"{letter.user_id} to {letter.exchange or '(default exchange)'} with {letter.routing_key!r}"
    try:
        connection = pika.BlockingConnection(parameters)
        try:
            confirms = PipelinedConfirms(connection, connection.channel(), SERVICE_CONFIRM_TIMEOUT_S)
            outcome = confirms.send_one(Outgoing(letter.exchange, letter.routing_key, letter.body, again))
        finally:
            if connection.is_open:
                connection.close()
    except (pika.exceptions.AMQPError, OSError, PublisherError, *CONNECTION_FAILED) as error:
        raise RequeueRefused(
            f"the broker refused it as {sender} ({type(error).__name__}: {error}); it stays a dead letter"
        ) from None
    _raise_unless_taken(outcome, sender)
