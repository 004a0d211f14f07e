"""The robot's sender: a thread that drains the outbox to the broker, in order, for as long as it runs.

It owns its own pika connection (pika connections belong to one thread), connects with backoff
while the broker is away, sends the oldest waiting events as one pipelined window, and removes
them from the outbox only once the broker confirmed them. A window whose confirms were lost with
the connection is sent again after reconnecting; the server's (robot, epoch, seq) key makes the
second copy harmless.

What goes wrong is one of two kinds, told apart here:

- **Refused**: the broker answered, and said no to this message: it closed the channel on it
  (access refused, a forged user id) or returned it as unroutable. Sending it again would get
  the same answer, so it is moved to the outbox's refused list with the reason, logged, and
  reported to the ``publish`` that waits for it; the events behind it carry on.
- **Outage**: the connection could not be made, broke, or the confirms did not come in time;
  or the broker nacked the message. A nack is RabbitMQ saying a queue cannot take it now (an
  internal error of the queue, or a queue that is full with ``reject-publish``), which says
  nothing about the message itself. The events stay in the outbox, in their place, and are sent
  again after a wait drawn by :func:`fleetbus.publishers.backoff.reconnect_delay`: exponential, with full
  jitter, capped at ``max_reconnect_delay``. A connection loss never marks a message refused.

After a nack the sender does not send its whole backlog again: it sends one event (the first to
go) and doubles the window with each window the broker takes whole, back up to
:data:`PUBLISH_WINDOW` (a TCP-like slow start). A site whose uplink is full nacks what is routed
there, but its other queues have taken the copies already, so every event sent again is a
duplicate there: with the backlog resent every few seconds, a robot made thirteen duplicates for
each real event in a 30-second outage of its site's uplink, with the probe about one per try.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import pika
import pika.credentials
import pika.exceptions

from fleetbus.publishers.backoff import reconnect_delay
from fleetbus.publishers.closing import close_quietly
from fleetbus.publishers.confirms import Outcome, Outgoing, PipelinedConfirms, WaitStopped, Window
from fleetbus.publishers.errors import CONNECTION_FAILED, BrokerUnavailable, PublishRefused, PublishTimeout
from fleetbus.publishers.handshake import broker_unverified, certificate_refusal
from fleetbus.publishers.login import login_refusal
from fleetbus.publishers.outbox import SEGMENT_EVENTS, Entry, Outbox, OutboxError

log = logging.getLogger("fleetbus.robot.sender")

#: Largest window written before waiting for its confirms; bounds memory and resend work. Whole
#: segments: a take stops before a segment it could only take part of, so 1,000 sent 768.
PUBLISH_WINDOW = 4 * SEGMENT_EVENTS
#: Windows written before the oldest one's confirms are awaited. The broker confirms a quorum
#: queue's messages once they are committed, in batches: with two windows of 768 it idled between
#: them. 4 of 1,024 (at most 4,096 events, about 3 MB, in flight and sent again after a lost
#: connection) drain at 0.60-0.73 of raw pika publishing where two reached 0.50-0.61; on a
#: saturated machine both are CPU-bound, alike (``python -m bench.outbox --windows 1000x2,1024x4``).
WINDOWS_IN_FLIGHT = 4
#: Nacks in a row after which the sender opens a new connection (to the next address that answers)
#: instead of trying on the same channel again: on RabbitMQ 3.10 a channel that reached a cluster
#: while a quorum queue's leader was being elected again kept nacking that queue's messages (for
#: minutes, measured), while a new connection's were confirmed at once.
NACKS_BEFORE_RECONNECT = 3
#: How often an idle sender lets pika answer heartbeats.
IDLE_TICK = 1.0
#: What ends a connection or a try to make one: the sender connects again after its backoff.
#: (OSError for the sockets: the outbox's own files raise :class:`OutboxError` instead.)
BROKER_LOST = (BrokerUnavailable, PublishTimeout, OSError, pika.exceptions.AMQPError, *CONNECTION_FAILED)
#: The window after a nack: one event, to learn whether the broker takes messages again.
PROBE_WINDOW = 1


def _abort(connection: pika.BlockingConnection) -> None:
    """Drop the socket at once. A graceful close waits for the broker's answer, which never comes
    when the network went silent (no RST): the sender would hang until the heartbeat timed out."""
    transport = getattr(connection._impl, "_transport", None)
    if transport is not None:
        transport.abort()
    connection.process_data_events(0)


class Nacked(Exception):
    """The broker nacked some events: they stay in the outbox and go again after a wait."""

    def __init__(self, count: int) -> None:
        super().__init__(f"the broker nacked {count} messages (a queue could not take them now)")
        self.count = count


class ExpressJob:
    """Events handed to the sender while the publishing thread writes them to the outbox."""

    def __init__(self, entries: list[Entry]) -> None:
        self.entries = entries
        self._sent = threading.Event()
        self._written = threading.Event()
        self._positioned: list[Entry] | None = None
        self._lock = threading.Lock()
        self._sending = False
        self._abandoned = False

    def start_sending(self) -> bool:
        """The sender is about to write them to its socket; False if their outbox write failed
        first (then they must not go: the publisher raised, saying none was sent)."""
        with self._lock:
            self._sending = not self._abandoned
            return self._sending

    def sent(self) -> None:
        self._sent.set()

    def wait_sent(self, timeout: float) -> None:
        self._sent.wait(timeout)

    def stored(self, entries: list[Entry]) -> None:
        self._positioned = entries
        self._written.set()

    def abandon(self) -> bool:
        """Their outbox write failed; True if the sender had begun sending them already."""
        with self._lock:
            self._abandoned = True
            sending = self._sending
        self._written.set()
        return sending

    def wait_stored(self, timeout: float) -> list[Entry] | None:
        """The entries with their outbox positions; None if the write failed or took too long."""
        return self._positioned if self._written.wait(timeout) else None


@dataclass
class Waiter:
    """A caller waiting for some of its events to be settled (confirmed or refused).

    Registered (:meth:`Sender.watch`) before the events are written to the outbox, so that a
    settle coming sooner than the caller's wait is not missed.
    """

    pending: set[str]
    refused: dict[str, str] = field(default_factory=dict)
    deferred: bool = False
    """The broker nacked one of them: it waits in the outbox for the next try."""


class Sender:
    def __init__(
        self,
        outbox: Outbox,
        parameters: list[pika.URLParameters],
        to_outgoing: Callable[[Entry], Outgoing],
        *,
        confirm_timeout: float,
        max_reconnect_delay: float,
        name: str,
        robot_id: str,
    ) -> None:
        self._outbox = outbox
        self._robot_id = robot_id
        self._parameters = parameters
        self._unverified = False
        """The last try to connect could not verify the broker's certificate."""
        self._login_refused: str | None = None
        """Why the broker refused the last try's login (the robot's credentials), or None."""
        self._certificate_login = any(
            isinstance(each.credentials, pika.credentials.ExternalCredentials) for each in parameters
        )
        self._to_outgoing = to_outgoing
        self._confirm_timeout = confirm_timeout
        self._max_delay = max_reconnect_delay
        self._condition = threading.Condition()
        self._stopping = False
        self._connected = False
        self._failures = 0
        """Connection attempts that failed and connections lost since the start: the sender is cut
        off when it is not connected and this is not 0 (before that, its first attempt is under way)."""
        self._retry_now = False
        self._work = False
        self._waiters: list[Waiter] = []
        self._express: ExpressJob | None = None
        self._busy = False
        self._settled = 0
        """Bumped at every settle, so a waiter cannot miss one."""
        self._connection: pika.BlockingConnection | None = None
        self._confirms: PipelinedConfirms | None = None
        self.last_error: str | None = None
        self._outbox_error: str | None = None
        """What the outbox's files last failed with, while they fail; None once they work."""
        self._outbox_failures = 0
        """Turns in a row that ended on an outbox error (the bound of the next wait doubles)."""
        self.sent = 0
        self._window = PUBLISH_WINDOW
        """Events a window takes now: :data:`PROBE_WINDOW` after a nack, doubling back up."""
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    # ------------------------------------------------------------------ control (any thread)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> bool:
        """Tell the thread to stop, and wait ``timeout`` at most for it to end; whether it ended.
        Its waits for the broker look at the stop: it ends within a fraction of a second, unless
        it is in the middle of opening a connection or of a write to the outbox's files."""
        with self._condition:
            self._stopping = True
            self._condition.notify_all()
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def join(self) -> None:
        """Wait for the thread to end, however long that takes (after :meth:`stop`)."""
        self._thread.join()

    def wake(self) -> None:
        with self._condition:
            self._work = True
            self._condition.notify_all()

    @property
    def connected(self) -> bool:
        return self._connected

    def offer_express(self, entries: list[Entry]) -> ExpressJob | None:
        """Take events to send right now, before they are durable in the outbox (see Outbox.append).

        Only while connected and idle: with anything else waiting, they go in order behind it.
        """
        with self._condition:
            if not self._connected or self._express is not None or self._busy:
                return None
            self._express = job = ExpressJob(entries)
            self._work = True
            self._condition.notify_all()
            return job

    @property
    def login_refused(self) -> str | None:
        """Why the broker refused the robot's login at the last try to connect, or None."""
        return self._login_refused

    def wait_connected(self, timeout: float) -> bool:
        """Wait until connected; False at ``timeout``, or at once when the broker's certificate
        could not be verified or the broker refused the robot's login (the sender goes on trying
        in the background: either may be fixed on the broker)."""
        with self._condition:
            self._condition.wait_for(
                lambda: self._connected or self._stopping or self._unverified or self._login_refused,
                timeout,
            )
            return self._connected

    def watch(self, message_ids: Sequence[str]) -> Waiter:
        """Start following these events' settles (before they are written; see :class:`Waiter`)."""
        waiter = Waiter(set(message_ids))
        with self._condition:
            self._waiters.append(waiter)
        return waiter

    def unwatch(self, waiter: Waiter) -> None:
        with self._condition:
            if waiter in self._waiters:
                self._waiters.remove(waiter)

    def wait_settled(
        self, waiter: Waiter, confirm_timeout: float, connect_timeout: float
    ) -> dict[str, str] | None:
        """Wait until the watched events are confirmed or refused, while the broker is reachable.

        Before the sender's first connection attempt has ended, wait for it (``connect_timeout`` at
        most); once it is connected, wait ``confirm_timeout`` at most for the broker's answers. Once
        the sender is cut off (an attempt failed, or the connection was lost), return at once.
        Returns the refused ones (message id -> reason), or None if the events were not all
        settled: then they simply wait in the outbox.
        """
        try:
            with self._condition:
                if not self._connected and not self._failures:
                    self._condition.wait_for(
                        lambda: self._connected or self._failures or self._stopping, connect_timeout
                    )
                if not self._connected:
                    return None
                done = self._condition.wait_for(
                    lambda: not waiter.pending or waiter.deferred or not self._connected or self._stopping,
                    confirm_timeout,
                )
                return waiter.refused if done and not waiter.pending else None
        finally:
            self.unwatch(waiter)

    def wait_drained(self, timeout: float) -> bool:
        """Wait until the outbox is empty; False if ``timeout`` passed first."""
        return self._wait_empty(timeout, give_up=lambda: False)

    def deliver(self, timeout: float) -> bool:
        """Try to deliver what waits before the robot stops: wait until the outbox is empty, for at
        most ``timeout``. A sender that is cut off tries to connect at once (not after its backoff),
        and the wait ends as soon as that attempt fails, or the connection is lost: then the
        broker is away, and what waits goes out with the robot's next run. False if anything waits."""
        with self._condition:
            failures = self._failures
            if not self._connected:
                self._retry_now = True
                self._condition.notify_all()
        return self._wait_empty(timeout, give_up=lambda: self._failures > failures and not self._connected)

    def _wait_empty(self, timeout: float, give_up: Callable[[], bool]) -> bool:
        deadline = time.monotonic() + timeout
        while True:
            with self._condition:
                settled, failures = self._settled, self._failures
            # the outbox is asked outside the condition: publishers take the outbox's lock first
            if not self._outbox.pending():
                return True
            remaining = deadline - time.monotonic()
            with self._condition:
                if remaining <= 0 or give_up():
                    return False
                if self._settled == settled and self._failures == failures:
                    self._condition.wait(min(remaining, IDLE_TICK))

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        failures = 0  # connection attempts failed and connections lost in a row
        nacks = 0  # tries in a row on which the broker nacked something
        while not self._stopping:
            try:
                failures, nacks = self._turn(failures, nacks)
            except Exception as error:  # never let the sender die: nor of what handling a failure raised
                log.exception("robot sender failed; retrying")
                try:
                    self._outbox.release()
                except Exception:  # the outbox's folder failing too: said above, tried again next turn
                    log.exception("robot sender could not put its events in flight back in the outbox")
                self._disconnect(repr(error))
                self._backoff(1.0)
        self._disconnect(None)

    def _turn(self, failures: int, nacks: int) -> tuple[int, int]:
        """One turn of the sender: connect, send an express event or drain, or wait; what went
        wrong handled (and counted in the two numbers it returns: failures and nacks in a row)."""
        try:
            if self._connection is None:
                self._connect()  # at once, not on the first event: publish() needs to know
                return failures, nacks
            with self._condition:
                job, self._express = self._express, None
                self._busy = True
            try:
                if job is not None:
                    self._send_express(job)
                    return failures, nacks
                drained = self._drain()
            finally:
                with self._condition:
                    self._busy = False
            self._outbox_failures = 0
            if not drained:
                self._idle_wait()
            return 0, 0  # the connection works, and the broker takes what it is sent
        except WaitStopped as stopped:
            # what was in flight waits in the outbox for the next run (the server drops a copy)
            log.info("robot sender stopping: %s", stopped)
            self._release()
            self._disconnect(None, abort=True)
            return failures, nacks
        except OutboxError as error:
            # the outbox's files, not the network: neither reconnect nor send anything again
            delay = reconnect_delay(self._outbox_failures, self._max_delay)
            self._outbox_failures += 1
            self._outbox_failed(error, delay)
            self._release()
            if self._connection is not None:
                self._pause(delay)
            else:
                self._backoff(delay)
            return failures, nacks
        except Nacked as nacked:
            delay = reconnect_delay(nacks, self._max_delay)
            nacks += 1
            if nacks % NACKS_BEFORE_RECONNECT == 0:
                log.warning("%s %d times in a row: reconnecting, next try in %.1f s", nacked, nacks, delay)
                self._release()
                self._disconnect(f"{nacked} {nacks} times in a row")
                self._backoff(delay)
                return failures, nacks
            log.warning("%s; they stay in the outbox, next try in %.1f s", nacked, delay)
            self._pause(delay)
            return failures, nacks
        except BROKER_LOST as error:
            self._release()
            connecting = self._connection is None
            self._unverified = connecting and broker_unverified(error)
            refusal = self._refusal(error) if connecting else None
            self._disconnect(refusal or self._failure(error, connecting))
            self._backoff(reconnect_delay(failures, self._max_delay))
            return failures + 1, nacks

    def _release(self) -> None:
        """Put what is in flight back in the outbox; an outbox error doing so is said, not raised."""
        try:
            self._outbox.release()
        except OutboxError as error:
            self._outbox_failed(error, None)

    def _outbox_failed(self, error: OutboxError, delay: float | None) -> None:
        """Say an outbox error once (until the outbox works again or fails otherwise); keep it."""
        message = str(error)
        with self._condition:
            new = message != self._outbox_error
            self._outbox_error = self.last_error = message
        if new:
            log.error(
                "robot %s: %s; the sender tries again (every %g s at most) without reconnecting or "
                "sending again what the broker has confirmed",
                self._robot_id,
                message,
                self._max_delay,
            )
        elif delay is not None:
            log.debug("robot %s: the outbox still fails; next try in %.1f s", self._robot_id, delay)

    def _outbox_works(self) -> None:
        with self._condition:
            failed, self._outbox_error = self._outbox_error, None
            if failed is not None and self.last_error == failed:
                self.last_error = None
        if failed is not None:
            log.warning("robot %s: the outbox works again", self._robot_id)

    def _refusal(self, error: BaseException) -> str | None:
        """Whether a try to connect failed on the robot's login; said once per refusal in a row."""
        refusal = login_refusal(error, self._robot_id)
        if refusal and not self._login_refused:
            log.error(
                "%s; events wait in the outbox, and the sender keeps trying (every %g s at most) "
                "in case the credentials are fixed on the broker",
                refusal,
                self._max_delay,
            )
        self._login_refused = refusal
        return refusal

    def _failure(self, error: BaseException, connecting: bool) -> str:
        """What went wrong; for a certificate login that could not connect, what that most
        likely means (the broker does not say it to the client)."""
        hint = certificate_refusal(error) if connecting and self._certificate_login else None
        return f"{hint}: {error!r}" if hint else repr(error)

    def _backoff(self, delay: float) -> None:
        """Wait before the next connection attempt; cut short by stop, or by a robot about to stop
        that wants one more try (:meth:`deliver`)."""
        with self._condition:
            self._condition.wait_for(lambda: self._stopping or self._retry_now, delay)
            self._retry_now = False

    def _pause(self, delay: float) -> None:
        """Wait while connected (after a nack), letting pika answer heartbeats; cut short by stop."""
        deadline = time.monotonic() + delay
        while True:
            remaining = deadline - time.monotonic()
            with self._condition:
                if remaining <= 0 or self._condition.wait_for(
                    lambda: self._stopping, min(remaining, IDLE_TICK)
                ):
                    return
            if self._connection is not None:
                self._connection.process_data_events(0)

    def _idle_wait(self) -> None:
        """Sleep until woken or a tick passes, then let pika answer heartbeats."""
        with self._condition:
            if not self._work:
                self._condition.wait(IDLE_TICK)
            woken, self._work = self._work, False
        # woken for work, go straight to it (sending pumps pika too): an express event is on the
        # wire about 0.06 ms sooner
        if not woken and self._connection is not None:
            self._connection.process_data_events(0)

    def _connect(self) -> None:
        connection = pika.BlockingConnection(self._parameters)
        try:
            confirms = PipelinedConfirms(
                connection, connection.channel(), self._confirm_timeout, lambda: self._stopping
            )
        except Exception:
            if self._stopping:
                _abort(connection)  # a graceful close waits for a broker that may not answer
            else:
                connection.close()
            raise
        self._connection, self._confirms = connection, confirms
        with self._condition:
            self._connected = True
            self._unverified = False
            refused, self._login_refused = self._login_refused, None
            self.last_error = None
            self._condition.notify_all()
        if refused:
            log.warning("the broker accepts robot %s's login again", self._robot_id)
        params = getattr(connection._impl, "params", None)
        log.info(
            "robot sender connected to %s:%s", getattr(params, "host", "?"), getattr(params, "port", "?")
        )

    def _disconnect(self, error: str | None, abort: bool = False) -> None:
        """Forget the connection, and close it: gracefully unless ``error`` or ``abort``."""
        connection, self._connection, self._confirms = self._connection, None, None
        with self._condition:
            if self._connected and error:
                log.warning("robot sender lost the broker: %s; events wait in the outbox", error)
            self._connected = False
            if error:
                self.last_error = error
                self._failures += 1
            self._condition.notify_all()
        if connection is not None and connection.is_open:
            try:
                if error or abort:
                    _abort(connection)
                else:
                    close_quietly(connection)
            except Exception:  # the connection is already broken; nothing more to do with it
                pass

    def _fresh_channel(self) -> PipelinedConfirms:
        assert self._connection is not None
        channel = self._connection.channel()
        self._confirms = PipelinedConfirms(
            self._connection, channel, self._confirm_timeout, lambda: self._stopping
        )
        return self._confirms

    def _drain(self) -> bool:
        """Send what waits, window after window, until the outbox has nothing more; False if it had
        nothing. The next window is written while the broker confirms the last one, so the outbox's
        disk work overlaps the broker's. Raises :class:`Nacked` once the windows in flight are
        settled if the broker nacked any of them."""
        assert self._confirms is not None
        confirms = self._confirms
        outstanding: deque[tuple[list[Entry], list[Outgoing], Window]] = deque()
        drained = False
        nacked = 0
        failed: OutboxError | None = None  # taking the next window: raised once those in flight settle
        try:
            while True:
                probing = self._window < PUBLISH_WINDOW
                if len(outstanding) < (1 if probing else WINDOWS_IN_FLIGHT) and not nacked and not failed:
                    try:
                        entries = self._outbox.take(self._window, whole_segments=True)
                    except OutboxError as error:
                        if not outstanding:
                            raise
                        failed, entries = error, []
                    if entries:
                        messages = [self._to_outgoing(entry) for entry in entries]
                        outstanding.append((entries, messages, confirms.write(messages)))
                        drained = True
                        continue
                if not outstanding:
                    if failed is not None:
                        raise failed
                    if nacked:
                        raise Nacked(nacked)
                    if drained:
                        self._outbox_works()
                    return drained
                entries, messages, window = outstanding[0]
                outcome = confirms.wait(window, self._confirm_timeout)
                outstanding.popleft()
                refused_now = self._settle_outcome(entries, outcome, entries)
                nacked += refused_now
                if refused_now:
                    self._window = PROBE_WINDOW
                elif len(entries) >= self._window:
                    self._window = min(PUBLISH_WINDOW, 2 * self._window)
        except PublishRefused:
            # The broker closed the channel on one of them: every window written is in doubt. Send
            # the oldest again one message at a time to find which; the rest go again after it.
            self._outbox.release()
            first = outstanding[0][0] if outstanding else self._outbox.take(PUBLISH_WINDOW)
            self._settle_one_by_one(first, [self._to_outgoing(entry) for entry in first])
            return True

    def _send_express(self, job: ExpressJob) -> None:
        """Send before the outbox write is done; settle once it is (the confirm may come first)."""
        assert self._confirms is not None
        confirms = self._confirms
        try:
            try:
                if not job.start_sending():
                    return  # the publisher could not store them, and said they were not sent
                window = confirms.write([self._to_outgoing(entry) for entry in job.entries])
                confirms.flush()
            finally:
                job.sent()  # the publisher may write them to the outbox now
            outcome = confirms.wait(window, self._confirm_timeout)
        except PublishRefused:
            # the entries wait in the outbox like any others; the normal path finds the culprit
            job.wait_stored(self._confirm_timeout)
            self._outbox.release()
            self._fresh_channel()
            return
        positioned = job.wait_stored(self._confirm_timeout)
        if positioned is None:
            log.error(
                "the outbox could not store %d events sent already: the publish raised "
                "OutboxWriteFailed, and they are not sent again unless enqueued again",
                len(job.entries),
            )
            self._outbox.release()
            return
        nacked = self._settle_outcome(positioned, outcome)
        self._outbox.release()
        if nacked:
            self._window = PROBE_WINDOW
            raise Nacked(nacked)

    def _settle_one_by_one(self, entries: list[Entry], messages: list[Outgoing]) -> None:
        try:
            for entry, message in zip(entries, messages, strict=True):
                confirms = self._confirms
                if confirms is None or confirms.closed:
                    confirms = self._fresh_channel()
                try:
                    outcome = confirms.send([message], self._confirm_timeout)
                except PublishRefused as error:
                    self._settle_outcome([entry], Outcome(set(), {}), refused={entry.message_id: str(error)})
                    continue
                if self._settle_outcome([entry], outcome):
                    raise Nacked(1)  # it and the ones after it stay, in order
        finally:
            self._outbox.release()

    def _settle_outcome(
        self,
        entries: list[Entry],
        outcome: Outcome,
        window: list[Entry] | None = None,
        refused: dict[str, str] | None = None,
    ) -> int:
        """Settle what the broker answered for ``entries``: confirmed ones leave the outbox, refused
        ones (returned as unroutable, or in ``refused``) move to its refused list, nacked ones stay
        for the next try. Returns how many were nacked."""
        refused = {
            **(refused or {}),
            **{mid: f"unroutable ({reason})" for mid, reason in outcome.returned.items()},
        }
        for entry in entries:
            if entry.message_id in refused:
                log.error(
                    "the broker refused %s %s/%d (%s); it is set aside, not sent again: %s",
                    entry.type,
                    entry.epoch,
                    entry.seq,
                    entry.message_id,
                    refused[entry.message_id],
                )
        self._settle(
            [e for e in entries if e.message_id not in outcome.nacked], refused, window, outcome.nacked
        )
        return len(outcome.nacked)

    def _settle(
        self,
        confirmed: list[Entry],
        refused: dict[str, str],
        window: list[Entry] | None = None,
        nacked: set[str] | frozenset[str] = frozenset(),
    ) -> None:
        self._settle_in_outbox(confirmed, refused, window)
        self.sent += len(confirmed) - len(refused)
        ids = {entry.message_id for entry in confirmed}
        with self._condition:
            for waiter in self._waiters:
                waiter.refused.update({m: why for m, why in refused.items() if m in waiter.pending})
                waiter.pending -= ids
                if waiter.pending & nacked:
                    waiter.deferred = True
            self._settled += 1
            self._condition.notify_all()

    def _settle_in_outbox(
        self, confirmed: list[Entry], refused: dict[str, str], window: list[Entry] | None
    ) -> None:
        """Settle in the outbox, trying again after a growing wait while its files fail: the broker
        answered already, so nothing is sent again meanwhile, and the connection is kept (pika
        answers its heartbeats during the wait). Raises the error once the sender is stopping."""
        attempt = 0
        while True:
            try:
                self._outbox.settle(confirmed, refused, window)
            except OutboxError as error:
                if self._stopping:
                    raise
                delay = reconnect_delay(attempt, self._max_delay)
                attempt += 1
                self._outbox_failed(error, delay)
                self._pause(delay)
                continue
            if attempt:
                self._outbox_works()
            return
