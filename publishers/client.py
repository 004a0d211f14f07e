"""The robot-side client: synchronous, on pika, for robot code that is usually synchronous.

with RobotClient(url, state_dir=...) as robot:    # the URL's user is the robot's account
    robot.publish("hazard", {...})                # durable in the outbox, then confirmed by the broker
    robot.publish_many([("status", {...}), ...])  # one outbox write, pipelined confirms
    for note in robot.notifications(timeout=5):   # this robot's inbox
        ...

Every event goes through the robot's outbox (its personal TinyDB database, on disk) and a sender
thread drains the outbox to the broker in order. ``publish`` waits for the broker's confirm while
the broker is reachable; once the sender is cut off it returns as soon as the event is on disk:
the event waits in the outbox and goes out, in order, when the broker is back, also after the
robot process restarted.
Right after the client started, the sender's first connection attempt is still under way:
``publish`` waits for it (``connect_timeout`` at most) before it decides either way. Leaving the
``with`` block delivers what still waits, for ``close_timeout`` at most.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import unquote, urlsplit

import pika
import pika.exceptions
from pika.adapters.blocking_connection import BlockingChannel
from pydantic import ValidationError

from fleetbus.publishers.backoff import reconnect_delay
from fleetbus.publishers.confirms import Outgoing
from fleetbus.publishers.errors import (
    CONNECTION_FAILED,
    BrokerUnavailable,
    ClientClosed,
    LoginRefused,
    PublisherError,
    PublishRefused,
)
from fleetbus.publishers.known import Known, KnownSubjects, subject_key
from fleetbus.publishers.login import LOGIN_REFUSED, login_refusal
from fleetbus.publishers.maps import FetchedMap, fetch_map, map_events
from fleetbus.publishers.outbox import LIMITS_VARIABLE, Entry, Outbox, TypePolicy, policies_with_limits
from fleetbus.publishers.rpc import RequestNotSent
from fleetbus.publishers.sender import Sender, Waiter
from fleetbus.publishers.sequence import SequenceCounter
from fleetbus.publishers.sessions import Sessions
from fleetbus.publishers.state_lock import StateLock
from fleetbus.publishers.tls import pika_parameter_list
from fleetbus.schemas.bodies import MapMetadata
from fleetbus.schemas.envelope import (
    EVENT_ADAPTER,
    Event,
    build_event,
    keyed_message_id,
    new_epoch,
    validate_body,
)
from fleetbus.schemas.identity import validate_name
from fleetbus.schemas.notifications import LATE_AFTER_S, Notification
from fleetbus.schemas.properties import EVENT_CONTENT_TYPE, PERSISTENT
from fleetbus.schemas.routing import (
    EventType,
    Topic,
    beacon_headers,
    event_routing_key,
    inbox_queue,
    publish_exchange,
)

log = logging.getLogger("fleetbus.robot")

#: The service's setting of when a notification is late, read by the robot too.
LATE_AFTER_VARIABLE = "FLEETBUS_LATE_AFTER_S"
#: How long :meth:`RobotClient.close` waits for the sender to stop once the delivery is over. The
#: sender's waits for the broker look at the stop flag every 50 ms: this is for the rest of a
#: connection attempt or of a write of the outbox. Past it, the state stays locked until it stops.
SENDER_STOP_S = 2.0
#: How often a listener given a ``stop`` event looks at it while its inbox is quiet.
STOP_CHECK_S = 0.5


def late_after_from_environment() -> float:
    """:data:`LATE_AFTER_VARIABLE` as the robot's environment sets it, else the default; raises
    ValueError naming the variable when it is not a number of seconds, 0 or more."""
    text = os.environ.get(LATE_AFTER_VARIABLE)
    if text is None:
        return LATE_AFTER_S
    try:
        seconds = float(text)
    except ValueError:
        seconds = -1.0
    if not seconds >= 0:  # also NaN
        raise ValueError(f"{LATE_AFTER_VARIABLE}: {text!r} is not a number of seconds, 0 or more")
    return seconds


def robot_folder(state_dir: Path, robot_id: str) -> Path:
    """The robot's personal database: sequence counter, outbox, lock."""
    return state_dir / robot_id


def outbox_folder(state_dir: Path, robot_id: str) -> Path:
    return robot_folder(state_dir, robot_id) / "outbox"


def missed_hazard(hazard: dict[str, Any], now: datetime, late_after_s: float = LATE_AFTER_S) -> Notification:
    """A hazard from ``hazard.open`` as the notification its warden missed; ``late`` as the service
    flags an announcement (``FLEETBUS_LATE_AFTER_S``, the robot's own setting of the same name)."""
    event = EVENT_ADAPTER.validate_python(hazard["event"])
    return Notification(
        topic=Topic.HAZARD,
        event=event,
        received_at=hazard["received_at"],
        notified_at=now,
        hazard_id=hazard["hazard_id"],
        hazard_state=hazard["state"],
        claimed_by=hazard.get("claimed_by"),
        late=(now - event.sent_at).total_seconds() > late_after_s,
    )


def outgoing(robot_id: str, entry: Entry) -> Outgoing:
    properties = pika.BasicProperties(
        content_type=EVENT_CONTENT_TYPE,
        delivery_mode=PERSISTENT,
        message_id=entry.message_id,
        user_id=robot_id,  # checked by the broker against the login
        timestamp=int(entry.sent_at.timestamp()),
        type=entry.type,
        app_id="fleetbus-robot",
        # beacons pass the robot's beacon exchange only with these headers
        headers=beacon_headers(robot_id) if entry.type == EventType.BEACON.value else None,
    )
    return Outgoing(
        publish_exchange(robot_id, entry.type),
        event_routing_key(robot_id, entry.type),
        entry.body,
        properties,
    )


def last_step_at(hazard: dict[str, Any]) -> datetime:
    """When a hazard (as the services give it) last changed: its latest time stamp."""
    stamps = ("received_at", "announced_at", "claimed_at", "reached_at", "cleared_at")
    times = [hazard[name] for name in stamps if hazard.get(name)]
    return max(value if isinstance(value, datetime) else datetime.fromisoformat(value) for value in times)


class RobotClient:
    """A robot's connection to fleetbus; one per robot process (its personal database is locked).

    ``connect_timeout``: how long :meth:`connect`, a service call's connection, and the first
    ``publish`` after the start wait for the broker. ``confirm_timeout``: how long ``publish``
    waits for the broker's answers once connected. ``close_timeout``: how long :meth:`close`
    (leaving the ``with`` block) tries to deliver what still waits in the outbox.
    ``max_reconnect_delay``: the cap of the waits between connection attempts (and between tries
    of what the broker nacked), which are drawn at random below an exponentially growing bound
    (:mod:`fleetbus.publishers.backoff`) so that a team does not reconnect in lockstep.
    ``outbox_policies``: each type's overflow and limit in the outbox; by default the outbox's
    defaults with the limits of ``FLEETBUS_OUTBOX_LIMITS`` (``status=500 localisation=100``).
    A status event the robot publishes carries, in ``outbox_dropped``, what its outbox dropped so
    far by type (unless the robot code set it), so that the operators see it in the team view.
    """

    def __init__(
        self,
        amqp_url: str,
        *,
        state_dir: Path | str,
        connect_timeout: float = 30.0,
        confirm_timeout: float = 10.0,
        close_timeout: float = 5.0,
        max_reconnect_delay: float = 5.0,
        outbox_policies: Mapping[str, TypePolicy] | None = None,
        durable: bool = True,
        late_after_s: float | None = None,
    ) -> None:
        """``late_after_s``: when a hazard the client hands out from its rebuilt list counts as
        late, as the service's ``FLEETBUS_LATE_AFTER_S`` (default: that variable, else 5 s)."""
        self.robot_id = validate_name(unquote(urlsplit(amqp_url).username or ""))
        self.epoch = new_epoch()
        """This client's epoch: its events are numbered 0, 1, 2, ... in it
        (:mod:`fleetbus.publishers.sequence`)."""
        self._sequence = SequenceCounter()
        self._storing = threading.Lock()
        """Held while events are numbered and appended to the outbox: they enter it in order."""
        self._late_after_s = late_after_from_environment() if late_after_s is None else late_after_s
        # every address of a cluster's URL, tried in turn at each (re)connection
        self._parameters = pika_parameter_list(
            amqp_url, heartbeat=30, connection_attempts=1, socket_timeout=5
        )
        self._where = ", ".join(f"{each.host}:{each.port}" for each in self._parameters)
        self._connect_timeout = connect_timeout
        self._confirm_timeout = confirm_timeout
        self._close_timeout = close_timeout
        self._max_reconnect_delay = max_reconnect_delay
        folder = robot_folder(Path(state_dir), self.robot_id)
        self._lock = StateLock(folder)
        self._lock.acquire()
        try:
            policies = outbox_policies
            if policies is None:
                policies = policies_with_limits(os.environ.get(LIMITS_VARIABLE, ""))
            self.outbox = Outbox(folder / "outbox", policies, durable=durable)
        except BaseException:
            self._lock.release()
            raise
        self._sender = Sender(
            self.outbox,
            self._parameters,
            lambda entry: outgoing(self.robot_id, entry),
            confirm_timeout=confirm_timeout,
            max_reconnect_delay=max_reconnect_delay,
            name=f"fleetbus-sender-{self.robot_id}",
            robot_id=self.robot_id,
        )
        self._started = False
        self._start_lock = threading.Lock()
        self._closed = False
        self._sessions = Sessions(self._open_connection, self.robot_id)
        """Each calling thread's connection for services and notifications (pika's are not
        thread-safe), apart from the sender's."""
        self._known = KnownSubjects()

    # connection
    def start(self) -> None:
        """Start draining the outbox in the background (connecting whenever the broker answers)."""
        with self._start_lock:  # close() reads whether it started under it: never a sender it missed
            self._refuse_if_closed()
            if self._started:
                return
            self._started = True
            self._sender.start()

    def connect(self, timeout: float | None = None) -> None:
        """Start, and wait until the sender reached the broker; raise BrokerUnavailable if it did
        not, LoginRefused (a BrokerUnavailable) at once when the broker refused the robot's login."""
        self.start()
        timeout = self._connect_timeout if timeout is None else timeout
        if not self._sender.wait_connected(timeout):
            refusal = self._sender.login_refused
            if refusal:
                raise LoginRefused(f"{refusal} (broker at {self._where})")
            raise BrokerUnavailable(
                f"cannot reach the broker at {self._where} within "
                f"{timeout:g} s: {self._sender.last_error or 'no answer'}"
            )

    @property
    def connected(self) -> bool:
        """Whether the sender has a connection to the broker now."""
        return self._sender.connected

    @property
    def last_error(self) -> str | None:
        """Why the sender last lost or could not reach the broker (a refused login among them), or
        why the outbox's files fail while they do (:class:`~fleetbus.publishers.outbox.OutboxError`)."""
        return self._sender.last_error

    def flush(self, timeout: float = 30.0) -> bool:
        """Wait until every waiting event is confirmed; False if ``timeout`` passed first.
        Raises :class:`ClientClosed` once the client was closed."""
        self.start()
        return self._sender.wait_drained(timeout)

    def close(self, flush_timeout: float | None = None) -> None:
        """Deliver what waits in the outbox, for ``flush_timeout`` at most (default: the client's
        ``close_timeout``), then stop. The delivery ends early when the broker is away: a sender
        that is cut off tries once more at once, and its failure ends the wait. Events not yet
        confirmed stay in the outbox for the next run.

        Returns within ``flush_timeout`` and :data:`SENDER_STOP_S` more: a sender waiting for a
        broker slow to confirm stops waiting. One still busy then (opening a connection, writing
        the outbox's files) is left to end in the background, logged, and the robot's state stays
        locked until it does, so that it never writes into files another client owns."""
        with self._storing:  # a publish under way stores its events first; later ones are refused
            if self._closed:
                return
            self._closed = True
        with self._start_lock:
            started = self._started
        try:
            timeout = self._close_timeout if flush_timeout is None else flush_timeout
            if timeout > 0 and started and self.outbox.pending():
                if not self._sender.deliver(timeout):
                    log.warning(
                        "%d events wait in %s's outbox for the next run: %s",
                        self.outbox.pending(),
                        self.robot_id,
                        self._sender.last_error or f"not confirmed within {timeout:g} s",
                    )
        finally:
            self._sessions.close()
            if not started or self._sender.stop(SENDER_STOP_S):
                self._let_go()
            else:
                log.error(
                    "%s's sender did not stop within %g s (opening a connection, or writing to the "
                    "outbox's files): the robot's state stays locked until it does",
                    self.robot_id,
                    SENDER_STOP_S,
                )
                threading.Thread(
                    target=self._let_go_once_stopped, name=f"fleetbus-closing-{self.robot_id}", daemon=True
                ).start()

    def _let_go(self) -> None:
        """Close the outbox and unlock the robot's state: another client may own them now."""
        self.outbox.close()
        self._lock.release()

    def _let_go_once_stopped(self) -> None:
        self._sender.join()
        self._let_go()
        log.warning("%s's sender stopped at last: the robot's state is unlocked", self.robot_id)

    def __enter__(self) -> RobotClient:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        """Leaving the block delivers what waits, for ``close_timeout`` at most, however it is
        left: an exception in robot code does not undo the events it published before."""
        self.close()

    # publishing
    def build(self, items: Sequence[tuple[EventType | str, Any]]) -> list[Event]:
        """Validate bodies, then give them this client's epoch and consecutive sequence numbers in it
        (none wasted on bad input), and ids named by those (:func:`keyed_message_id`).

        Events built here and handed to :meth:`enqueue` enter the outbox in the order the calls
        to ``enqueue`` come; :meth:`publish_many` numbers and stores in one step instead, so that
        the events of robot code publishing from several threads are stored in number order."""
        return self._numbered(self._validated(items))

    def _validated(self, items: Iterable[tuple[EventType | str, Any]]) -> list[tuple[EventType | str, Any]]:
        return [(event_type, validate_body(event_type, body)) for event_type, body in items]

    def _numbered(self, bodies: list[tuple[EventType | str, Any]]) -> list[Event]:
        if any(EventType(t) is EventType.STATUS and b.outbox_dropped is None for t, b in bodies):
            dropped = dict(self.outbox.dropped())
            if dropped:
                bodies = [
                    (t, b.model_copy(update={"outbox_dropped": dropped}))
                    if EventType(t) is EventType.STATUS and b.outbox_dropped is None
                    else (t, b)
                    for t, b in bodies
                ]
        first = self._sequence.reserve(len(bodies)) if bodies else 0
        robot, epoch = self.robot_id, self.epoch
        return [
            build_event(t, robot, epoch, seq, body, message_id=keyed_message_id(robot, epoch, seq))
            for seq, (t, body) in enumerate(bodies, start=first)
        ]

    def publish(self, event_type: EventType | str, body: Any, *, wait: bool = True) -> Event:
        return self.publish_many([(event_type, body)], wait=wait)[0]

    def publish_many(self, items: Iterable[tuple[EventType | str, Any]], *, wait: bool = True) -> list[Event]:
        """Validate, number and store the events in the outbox, then (``wait``) await their confirms.

        Numbering and storing are one step, under one lock (not held while the confirms are
        awaited): with several threads publishing, the outbox holds, and the broker and the
        store receive, the robot's events in the order they were numbered.

        Raises SchemaError for a bad body (nothing is stored), OutboxFull when a type that is never
        dropped reached its outbox limit, PublishRefused when the broker refused one of them,
        ClientClosed once the client was closed (nothing is stored), OutboxWriteFailed when the
        outbox could not store them all (a full disk): it says how many were kept and whether the
        others may have been sent, and holds the events, to hand to :meth:`enqueue` again.
        """
        self._refuse_if_closed()
        bodies = self._validated(items)
        self.start()
        with self._storing:
            events = self._numbered(bodies)
            waiter = self._store(events, wait)
        self._await_settled(waiter)
        return events

    def enqueue(self, events: Sequence[Event], *, wait: bool = True) -> None:
        """Put already built events in the outbox (a resend keeps its epoch and number: no second record).

        With ``wait``, return once the broker confirmed them; right after the start, the sender's
        first connection attempt is awaited first (``connect_timeout`` at most). Return at once
        when the sender is cut off (that attempt failed, or the connection was lost since), and
        after ``confirm_timeout`` at most while connected: the events then wait in the outbox and
        go out when the broker is back. Without ``wait``, return once they are in the outbox.
        Raises ClientClosed once the client was closed (nothing is stored).
        """
        self.start()
        with self._storing:
            waiter = self._store(events, wait)
        self._await_settled(waiter)

    def _refuse_if_closed(self) -> None:
        if self._closed:
            raise ClientClosed(f"the robot client of {self.robot_id} is closed: it takes no more events")

    def _store(self, events: Sequence[Event], wait: bool) -> Waiter | None:
        """Append ``events`` to the outbox (under :attr:`_storing`); their waiter when ``wait``.
        Raises :class:`ClientClosed` once the client was closed (its outbox and lock let go)."""
        self._refuse_if_closed()
        waiter = self._sender.watch([str(e.message_id) for e in events]) if wait else None
        try:
            self.outbox.append(events, express=self._sender.offer_express)
        except BaseException:
            if waiter is not None:
                self._sender.unwatch(waiter)
            raise
        finally:
            self._sender.wake()  # also for those an OutboxWriteFailed says were kept
        return waiter

    def _await_settled(self, waiter: Waiter | None) -> None:
        if waiter is None:
            return
        refused = self._sender.wait_settled(waiter, self._confirm_timeout, self._connect_timeout)
        if refused:
            raise PublishRefused("; ".join(f"{mid}: {reason}" for mid, reason in refused.items()))

    # services
    def call(self, method: str, timeout: float = 5.0, **params: Any) -> Any:
        """Call a fleetbus service; raise ServiceTimeout when no reply comes within ``timeout``.
        Each thread calls on a connection of its own.

        A call whose connection or channel is found dead before its request is sent (the broker
        restarted, or closed the connection while the robot was idle) reconnects and sends it
        once more; a request that may have reached the service is never sent again: a call that
        loses its connection after sending raises BrokerUnavailable, one not answered in time
        ServiceTimeout."""
        try:
            return self._sessions.rpc().call(method, params, timeout)
        except RequestNotSent as error:
            log.info("%s; reconnecting to call it", error)
            return self._sessions.rpc().call(method, params, timeout)

    def hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        """One hazard this robot reported, or one open to it as :meth:`open_hazards` would list
        it; ServiceRefused for another warden's, a cleared one or a site's."""
        return self.call("hazard.get", timeout, hazard_id=hazard_id)

    def open_hazards(self, timeout: float = 5.0) -> list[dict[str, Any]]:
        return self.call("hazard.open", timeout)

    def claim_hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self._step("hazard.claim", hazard_id, timeout)

    def release_hazard(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self._step("hazard.release", hazard_id, timeout)

    def hazard_reached(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self._step("hazard.reached", hazard_id, timeout)

    def hazard_cleared(self, hazard_id: int, timeout: float = 5.0) -> dict[str, Any]:
        return self._step("hazard.cleared", hazard_id, timeout)

    def _step(self, method: str, hazard_id: int, timeout: float) -> dict[str, Any]:
        """A step of this warden's; the hazard's new state is what it knows of it from now on, so
        that the news of a step taken for it later (released by an operator) is handed out."""
        hazard: dict[str, Any] = self.call(method, timeout, hazard_id=hazard_id)
        key = subject_key(Topic.HAZARD, hazard["event"]["message_id"])
        self._known.know(key, Known(hazard["state"], hazard.get("claimed_by"), last_step_at(hazard)))
        return hazard

    def wardens(self, timeout: float = 5.0) -> list[dict[str, Any]]:
        return self.call("wardens", timeout)

    def publish_map(
        self, pgm: bytes, metadata: MapMetadata | dict[str, Any], created_at: datetime | None = None
    ) -> list[Event]:
        """Publish a map (PGM bytes and YAML fields); large images go as chunks, in one pipelined batch."""
        return self.publish_many(map_events(pgm, metadata, created_at))

    def fetch_map(self, version: int | None = None, timeout: float = 10.0) -> FetchedMap:
        """The latest (or a given) stored map, byte for byte."""
        return fetch_map(self, version, timeout)

    def beacon_info(self, beacon_id: str, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("beacon.info", timeout, beacon_id=beacon_id)

    def stranded(self, minutes: float = 10, timeout: float = 5.0) -> list[dict[str, Any]]:
        """Beacons heard in the last ``minutes``: where people are likely stranded."""
        return self.call("beacon.stranded", timeout, minutes=minutes)

    def beacon_goal(self, minutes: float = 10, timeout: float = 5.0) -> dict[str, Any] | None:
        """The guide's next beacon: the first heard of the recent ones not visited yet."""
        return self.call("beacon.goal", timeout, minutes=minutes)

    def beacon_visited(self, beacon_id: str, timeout: float = 5.0) -> dict[str, Any]:
        return self.call("beacon.visited", timeout, beacon_id=beacon_id)

    # notifications
    def notifications(
        self, timeout: float | None = None, prefetch: int = 64, stop: threading.Event | None = None
    ) -> Iterator[Notification]:
        """This robot's notifications; stops after ``timeout`` seconds without one, or once ``stop``
        is set (looked at every :data:`STOP_CHECK_S`). A listener that runs until told to stop
        passes ``stop`` and no ``timeout``: it keeps one consumer open instead of opening and
        closing one per quiet ``timeout`` (four round trips to the broker each time).

        Each thread listens on a connection of its own, so one thread may listen while others
        publish and call the services; :meth:`close` ends a listener on another thread quietly
        (within :data:`STOP_CHECK_S` when it waits with ``stop``).

        Each notification is acked when the caller asks for the next one or leaves the loop,
        however it leaves it: ``break``, ``return`` and an exception raised while handling it
        alike (Python closes a generator the same way for each, and does not tell it why), so a
        notification whose handling raised is acked and not delivered again; robot code that
        must not lose one catches its own errors inside the loop. One that was being handled
        when the robot process died is delivered again. The service
        sends at least once (it announces again when it cannot be sure a broker took the first
        announcement); a notification that tells this client nothing new (a copy of one it handed
        out, or one older than what it learned since) is acked and skipped. One it cannot read (a
        newer server's) is logged and rejected: the workers count it (`fleetbus stats`,
        ``<robot>.inbox rejected``).

        A warden in service first gets the open hazards it missed: on its first call and after
        every reconnect, the client asks the service (``hazard.open``) and hands out, in order,
        each announced hazard it has not handed out yet (its inbox lost or purged, or filled
        while it was away), with its state; the service leaves out those another warden holds
        (claimed or reached), and gives back those this warden holds.
        """
        if self._sessions.closed:
            raise ClientClosed("the robot client is closed")
        try:
            yield from self._listen(timeout, prefetch, stop)
        except (pika.exceptions.AMQPError, ClientClosed):
            if self._sessions.closed:
                return  # close() closed this thread's connection: the listen is over
            raise

    def _listen(
        self, timeout: float | None, prefetch: int, stop: threading.Event | None
    ) -> Iterator[Notification]:
        channel = self._open_consumer_channel()
        try:
            yield from self._missed_hazards()
            channel.basic_qos(prefetch_count=prefetch)
            quiet_since = time.monotonic()
            inactivity = timeout if stop is None else min(timeout or STOP_CHECK_S, STOP_CHECK_S)
            for method, _, body in channel.consume(inbox_queue(self.robot_id), inactivity_timeout=inactivity):
                if stop is not None and stop.is_set():
                    return  # a delivery not yet handed out is not acked: it comes again
                if method is None:
                    if timeout is not None and time.monotonic() - quiet_since >= timeout:
                        return
                    continue
                quiet_since = time.monotonic()
                try:
                    note = Notification.model_validate_json(body)
                except ValidationError as error:
                    # set aside, not acked: the inbox's dead-letter exchange has the workers count
                    # it (`fleetbus stats`: <robot>.inbox rejected); a server newer than this client?
                    log.error("a notification this client cannot read, set aside: %s", error)
                    channel.basic_reject(method.delivery_tag, requeue=False)
                    continue
                try:
                    if self._known.seen_before(note):
                        continue
                    yield note
                finally:  # the caller asked for the next one, or stopped iterating
                    if channel.is_open:
                        channel.basic_ack(method.delivery_tag)
        finally:
            if channel.is_open:
                channel.cancel()
                channel.close()

    def _missed_hazards(self) -> Iterator[Notification]:
        """Once per connection, for a warden in service: the open hazards not handed out yet."""
        session = self._sessions.mine()
        connection = session.connection
        if connection is None or connection is session.resynced_on:
            return
        try:
            me = next((w for w in self.wardens() if w["name"] == self.robot_id), None)
            hazards = self.open_hazards() if me is not None and me.get("in_service", True) else []
        except PublisherError as error:
            log.warning(
                "could not rebuild the list of open hazards (%s); trying again at the next call", error
            )
            return
        now = datetime.now(timezone.utc)
        for hazard in hazards:
            if hazard["state"] == "held":  # not announced yet: it comes through the inbox
                continue
            note = missed_hazard(hazard, now, self._late_after_s)
            if not self._known.seen_before(note, resync_as_of=last_step_at(hazard)):
                yield note
        session.resynced_on = connection  # only once all were handed out: a caller may stop early

    def _open_connection(self) -> pika.BlockingConnection:
        """A new connection for the calling thread (services, notifications), with retries.

        Separate from the sender's: a pika connection belongs to one thread.
        """
        deadline = time.monotonic() + self._connect_timeout
        attempt = 0
        while True:
            try:
                return pika.BlockingConnection(self._parameters)
            except LOGIN_REFUSED as error:  # trying again would not help
                raise LoginRefused(
                    f"{login_refusal(error, self.robot_id)} (broker at {self._where})"
                ) from error
            except CONNECTION_FAILED as error:
                delay = reconnect_delay(attempt, self._max_reconnect_delay)
                attempt += 1
                if time.monotonic() + delay > deadline:
                    raise BrokerUnavailable(
                        f"cannot reach the broker at {self._where} "
                        f"within {self._connect_timeout:g} s: {error!r}"
                    ) from error
                time.sleep(delay)  # the caller's own thread waits for its connection

    def _open_consumer_channel(self) -> BlockingChannel:
        """A new channel, reconnecting first when the connection is gone (the broker restarted)."""
        try:
            return self._sessions.connection().channel()
        except pika.exceptions.AMQPError:
            self._sessions.forget()  # it died under us; start a new one
            return self._sessions.connection().channel()

    def receive(self, count: int, timeout: float) -> list[Notification]:
        """Exactly ``count`` notifications, or fewer if ``timeout`` passes first."""
        received: list[Notification] = []
        deadline = time.monotonic() + timeout
        while len(received) < count and time.monotonic() < deadline:
            try:
                for note in self.notifications(timeout=max(0.1, deadline - time.monotonic())):
                    received.append(note)
                    if len(received) == count:
                        break
            except pika.exceptions.AMQPError:
                continue  # the broker went away; the unacked notification comes again after reconnecting
        return received
