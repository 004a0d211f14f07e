"""The fleetbus side of the live ROS bridge: runs the ROS side, records, maps, and talks back.

The ROS side (:mod:`ros_side`, a script for the ROS machine's own Python) discovers and reads
the topics and writes each message as a JSON line. This side reads those lines into a bounded
queue, applies the per-topic rate limit, turns mapped messages into fleetbus events (the mapping
file) and every other one into a ``ros`` event, and hands them to the robot client: its outbox
keeps them until the broker confirmed them. This robot's notifications go the other way, as
lines the ROS side publishes on ROS topics. What is dropped anywhere is counted per topic, with
its reason, in the log's status lines and the status file.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import subprocess
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any

import pika.exceptions

from fleetbus.publishers.client import RobotClient, robot_folder
from fleetbus.publishers.errors import PublisherError
from fleetbus.publishers.maps import map_events
from fleetbus.publishers.outbox import OutboxFull, OutboxWriteFailed
from fleetbus.publishers.ros.commands import follow_commands
from fleetbus.publishers.ros.convert import (
    hazard_body,
    localisation_body,
    notification_messages,
    occupancy_grid_map,
    ros_stamp,
)
from fleetbus.publishers.ros.counters import Counters, DropReason, RateLimit
from fleetbus.publishers.ros.held import HeldQueue
from fleetbus.publishers.ros.mapping import Mapping, Rule
from fleetbus.publishers.ros.parts import supervised
from fleetbus.publishers.ros.side_log import BoundedLog, copy_lines
from fleetbus.schemas.bodies import RosChunk
from fleetbus.schemas.envelope import validate_body
from fleetbus.schemas.ros import BLOB_FROM, TRUNCATED_KEY, byte_arrays, schema_key, to_blobs, with_raw
from fleetbus.schemas.routing import EventType

log = logging.getLogger("fleetbus.ros")

ROS_SIDE = Path(__file__).with_name("ros_side.py")
#: Messages taken from the queue into one outbox write at most.
BATCH = 256
#: How often a linger looks whether the bridge is stopping.
STOP_CHECK_S = 0.2
#: How long a stopping bridge reads its ROS side's last lines at most, once that side has ended.
END_READ_S = 5.0
#: The ROS topics notifications are published on start with this.
NOTIFY_PREFIX = "/fleetbus"
STATUS_FILE = "ros-bridge.json"
ROS_LOG_FILE = "ros-side.log"
#: Where the lines the ROS side's log could not take are counted, as a topic.
ROS_LOG_TOPIC = f"({ROS_LOG_FILE})"
ROS1_DEFINITION = "ros1msg"
"""A live connection's definition: ROS 1's message definition text (MCAP's schema encoding)."""
#: The parts of the bridge, as ``fleetbus ros status`` names them (:mod:`.parts`).
ROS_SIDE_PART, WRITER_PART, ROS_LOG_PART = "ros-side", "writer", "ros-log"
NOTIFICATIONS_PART, COMMANDS_PART = "notifications", "commands"

Item = tuple[EventType, Any]


def ros2_type_name(type_name: str) -> str:
    """``sensor_msgs/Image`` as ``sensor_msgs/msg/Image``: how fleetbus names ROS types in the
    recording, for ROS 1 and ROS 2 alike (as bag imports do)."""
    package, _, name = type_name.partition("/")
    return f"{package}/msg/{name}" if name and "/" not in name else type_name


def now() -> datetime:
    return datetime.now(timezone.utc)


def chunk_events(blobs: dict[str, bytes]) -> list[Item]:
    """The ``ros_chunk`` events carrying ``blobs`` (by SHA-256), each blob's in order: they go
    before the ``ros`` event that names them."""
    pieces = (chunk for blob, data in blobs.items() for chunk in RosChunk.pieces_of(blob, data))
    return [(EventType.ROS_CHUNK, chunk) for chunk in pieces]


def _read_exactly(stream: IO[bytes], length: int) -> bytes:
    data = stream.read(length)
    if len(data) != length:
        raise ValueError(f"the ROS side's output ended inside a byte array ({len(data)} of {length} bytes)")
    return data


@dataclass(frozen=True)
class Converted:
    """One ROS message's events, and what the counters say of it once they are in the outbox."""

    topic: str
    events: list[Item]
    over_bound: bool
    """It holds a byte array over the bound, only described."""

    @property
    def mapped(self) -> bool:
        return self.events[-1][0] is not EventType.ROS  # a mapping rule's events follow the ros one

    @property
    def blobs(self) -> int:
        """Byte arrays it sends whole, as ``ros_chunk`` events."""
        return sum(1 for kind, body in self.events if kind is EventType.ROS_CHUNK and body.index == 0)


class RosSideError(RuntimeError):
    """The ROS side could not start or ended; the message says how and where its log is."""


@dataclass(frozen=True)
class BridgeOptions:
    python: str = "/usr/bin/python3"
    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    max_rate_hz: float = 0.0
    discover_every_s: float = 1.0
    retry_most_s: float = 10.0
    """The longest wait between two tries of a master that does not answer (backing off)."""
    queue: int = 10_000
    queue_bytes: int = 64 * 1024 * 1024
    """The bytes held on each side of the pipe at most (``FLEETBUS_ROS_QUEUE_BYTES``)."""
    blob_max: int = 16 * 1024 * 1024
    """The largest byte array kept whole (``FLEETBUS_ROS_BLOB_MAX_BYTES``); a larger one is described."""
    status_every_s: float = 10.0
    linger_s: float = 0.25
    """How long the bridge gathers messages into one outbox write (``FLEETBUS_ROS_LINGER_S``)."""
    log_max_bytes: int = 10 * 1024 * 1024
    """The ROS side's log's size at most, and its older file's (``FLEETBUS_ROS_LOG_MAX_BYTES``)."""
    ready_timeout_s: float = 30.0
    ros_env: dict[str, str] | None = None
    """The ROS side's environment (default: this process's, with its ``ROS_MASTER_URI``)."""
    extra_args: tuple[str, ...] = field(default=())

    def ros_side_command(self, urgent: Sequence[str] = ()) -> list[str]:
        """``urgent``: the topics (patterns) of the mapping's rules, whose messages the ROS side
        sends at once; it gathers the others' for a linger, into one write to the pipe."""
        command = [self.python, str(ROS_SIDE), "--discover-every", str(self.discover_every_s)]
        command += ["--retry-most", str(self.retry_most_s), "--parent", str(os.getpid())]
        command += [
            "--bytes-max",  # arrays up to BLOB_FROM travel inline whatever the bound
            str(max(self.blob_max, BLOB_FROM)),
            "--queue",
            str(self.queue),
            "--queue-bytes",
            str(self.queue_bytes),
            "--raw-from",
            str(BLOB_FROM),
            "--own-prefix",
            NOTIFY_PREFIX,
            "--linger",
            str(self.linger_s),
        ]
        for pattern in urgent:
            command += ["--urgent", pattern]
        for pattern in self.include:
            command += ["--include", pattern]
        for pattern in self.exclude:
            command += ["--exclude", pattern]
        return command + list(self.extra_args)


class Bridge:
    """One robot's bridge; :meth:`run` until the ROS side ends or :meth:`stop` is called."""

    def __init__(
        self,
        robot: RobotClient,
        mapping: Mapping,
        options: BridgeOptions,
        state_dir: Path,
        commands_url: str | None = None,
    ) -> None:
        """``commands_url``: the robot's URL, to read its operator's commands (none: not read)."""
        self.robot = robot
        self.commands_url = commands_url
        self.mapping = mapping
        self.options = options
        self.counters = Counters()
        self.status_file = robot_folder(state_dir, robot.robot_id) / STATUS_FILE
        self.ros_log = robot_folder(state_dir, robot.robot_id) / ROS_LOG_FILE
        self._side_log = BoundedLog(self.ros_log, options.log_max_bytes)
        self._log_copy: threading.Thread | None = None
        self._queue: HeldQueue[dict[str, Any]] = HeldQueue(options.queue, options.queue_bytes)
        self._rate = RateLimit(options.max_rate_hz)
        self._stop = threading.Event()
        self._ended = threading.Event()
        """Set when the running ROS side's output ended (it ended, or its reader did)."""
        self._batch_ended = threading.Event()
        """Set when the ROS side ended a batch of messages: the writer takes it."""
        self._side_failure: str | None = None
        """What the running ROS side said of its own failure, before it ended."""
        self._stdin_lock = threading.Lock()
        self._process: subprocess.Popen[bytes] | None = None
        self._latched: dict[str, dict[str, Any]] = {}
        """The last message sent for each ROS topic (the ROS side latches them all): a new ROS
        side is handed these first, so that a node subscribing after a restart gets them."""
        self._last_pose: dict[str, Any] | None = None
        self._schema_keys: dict[tuple[str, str], str] = {}

    # the ROS side
    def start_ros_side(self) -> None:
        """Start the ROS side and wait until it runs; RosSideError (it is ended) when it does not."""
        started, ended = threading.Event(), threading.Event()
        self._side_failure = None
        try:
            self._side_log.open()  # there, 0600, from the first start
        except OSError as error:  # its lines are counted as dropped: no reason not to record
            log.warning("cannot open %s: %s", self.ros_log, error)
        try:
            process = subprocess.Popen(
                self.options.ros_side_command([rule.topic for rule in self.mapping.rules]),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                env=self.options.ros_env,
                bufsize=1 << 16,
            )
        except OSError as error:
            raise RosSideError(
                f"cannot start the ROS side with {self.options.python!r} (FLEETBUS_ROS_PYTHON): {error}"
            ) from None
        self._log_copy = self._copy_log(process)
        with self._stdin_lock:  # before any newer message, so that the newest stays latched
            self._process, self._ended = process, ended
            self._write_to_ros(process, list(self._latched.values()))
        threading.Thread(
            target=self._read, args=(process.stdout, started, ended), name="ros-reader", daemon=True
        ).start()
        deadline = time.monotonic() + self.options.ready_timeout_s
        while not started.wait(0.1):
            if ended.is_set() or time.monotonic() > deadline or self._stop.is_set():
                self._end_ros_side()
                raise RosSideError(
                    f"the ROS side did not start (is ROS installed for {self.options.python}?): "
                    f"see {self.ros_log}"
                )
        self.counters.parts.started(ROS_SIDE_PART)

    def _copy_log(self, process: subprocess.Popen[bytes]) -> threading.Thread:
        """The ROS side's stderr into its bounded log until it ends, as a part of its own: started
        again should it fail, as a ROS side whose pipe is not read would block once it is full."""
        assert process.stderr is not None
        stream, ended = process.stderr, threading.Event()

        def copy() -> None:
            copy_lines(
                stream, self._side_log, lambda: self.counters.drop(ROS_LOG_TOPIC, DropReason.LOG_FAILED)
            )
            ended.set()

        return supervised(ROS_LOG_PART, copy, self.counters.parts, ended)

    def _read(self, stream: IO[bytes], started: threading.Event, ended: threading.Event) -> None:
        """Every line of the ROS side, until its output ends: then ``ended`` (the bridge starts it
        again, or ends). A line it cannot take is logged and counted, never the reader's end."""
        try:
            for line in stream:
                try:
                    self._take_line(line, started, stream)
                except Exception as error:  # a line we did not expect must not stop the reading
                    self.counters.drop("(ros side)", DropReason.UNREADABLE)
                    log.warning("the ROS side wrote a line the bridge cannot take (%r): %r", error, line[:90])
        finally:
            ended.set()

    def _take_line(self, line: bytes, started: threading.Event, stream: IO[bytes]) -> None:
        item = json.loads(line)
        kind = item.get("kind")
        if kind == "message":
            size = len(line)
            if item.get("raw"):  # its large byte arrays follow the line, as they are
                raw = [_read_exactly(stream, length) for length in item.pop("raw")]
                item["fields"] = with_raw(item["fields"], raw)
                size += sum(map(len, raw))
            if not self._queue.offer(item, size):  # its parsed size, about
                self.counters.drop(item["topic"], DropReason.BRIDGE_QUEUE)
        elif kind == "batch-end":
            self._batch_ended.set()
        elif kind == "subscribed":
            self.counters.types[item["topic"]] = item["type"]
            log.info("recording %s (%s)", item["topic"], item["type"])
        elif kind == "dropped":
            for topic, count in item["counts"].items():
                self.counters.drop(topic, DropReason.ROS_QUEUE, count)
        elif kind == "error":
            self.counters.drop(item.get("topic") or "(publish)", DropReason.UNREADABLE)
            log.warning("ROS side: %s: %s", item.get("topic"), item.get("detail"))
        elif kind == "master":
            self._master(item)
        elif kind == "started":
            self.counters.ros_side = "waiting for the master"
            started.set()
        elif kind == "ready":
            self.counters.ros_side = "running"
        elif kind == "failed":
            self._side_failure = f"its {item.get('part')} failed: {item.get('detail')}"
            log.error("the ROS side's %s failed: %s", item.get("part"), item.get("detail"))

    def _master(self, item: dict[str, Any]) -> None:
        state, uri, restarted = item["state"], item.get("uri") or "", bool(item.get("restarted"))
        detail, retry_in = item.get("detail") or "", item.get("retry_in") or 0.0
        self.counters.master_said(state, detail, uri, retry_in, restarted)
        self.counters.write(self.status_file)
        if state == "running":
            log.info("the ROS master at %s answers%s", uri, " (restarted: registered again)" * restarted)
        else:
            log.warning("the ROS master at %s does not answer (%s); next in %.1f s", uri, detail, retry_in)

    def send_to_ros(self, items: list[dict[str, Any]]) -> None:
        with self._stdin_lock:
            for item in items:
                self._latched[item["topic"]] = item
            if self._process is not None:
                self._write_to_ros(self._process, items)

    def _write_to_ros(self, process: subprocess.Popen[bytes], items: list[dict[str, Any]]) -> None:
        """Under ``_stdin_lock``. What a ROS side that is gone did not get is counted; the newest
        of each topic is still handed to the next one."""
        if not items or process.stdin is None:
            return
        data = "".join(json.dumps(item) + "\n" for item in items).encode()
        try:
            process.stdin.write(data)
            process.stdin.flush()
        except (BrokenPipeError, ValueError):
            for item in items:  # a ROS side that restarts: counted, as every other drop
                self.counters.drop(item.get("topic") or "(publish)", DropReason.ROS_SIDE_GONE)
            log.warning("the ROS side is gone: %d messages for ROS not published", len(items))

    # messages to events
    def events_of(self, item: dict[str, Any]) -> list[Item]:
        """The fleetbus events of one ROS message (validated): the ``ros_chunk`` events of its
        large byte arrays, the message itself as a ``ros`` event naming them, then what its
        mapping rule makes of it; raises ConversionError or SchemaError when the message itself
        cannot be recorded. A message its rule cannot map is still recorded, and counted."""
        topic, type_name, fields = item["topic"], item["type"], item["fields"]
        stamp = ros_stamp(item.get("stamp_ns"))
        ros_type = ros2_type_name(type_name)
        blobs: dict[str, bytes] = {}
        kept = to_blobs(fields, blobs, self.options.blob_max)
        body = {
            "topic": topic,
            "ros_type": ros_type,
            "log_time_ns": item["received_ns"],
            "stamp": stamp.isoformat() if stamp else None,
            "fields": kept,
            "schema_key": self._schema_key(topic, ros_type, item),
        }
        if item.get("definition"):
            text, md5sum = item["definition"], item.get("md5sum")
            body["definition"] = {"encoding": ROS1_DEFINITION, "text": text, "md5sum": md5sum}
        recorded = [*chunk_events(blobs), (EventType.ROS, validate_body(EventType.ROS, body))]
        rule = self.mapping.rule_for(topic, type_name)
        if rule is None:
            return recorded
        try:
            return [*recorded, *self.mapped(rule, fields, stamp or ros_stamp(item["received_ns"]))]
        except Exception as error:  # (ConversionError, SchemaError...): the event only, not the record
            self.counters.drop(topic, DropReason.NOT_MAPPED)
            log.warning("%s (%s) recorded, but made no %s: %s", topic, type_name, rule.event, error)
            return recorded

    def _schema_key(self, topic: str, ros_type: str, item: dict[str, Any]) -> str | None:
        """The key of the message's type definition: made from the first message of its kind,
        which carries the definition, and kept for the others."""
        kind = (topic, item.get("md5sum") or "")
        if item.get("definition"):
            self._schema_keys[kind] = schema_key(ROS1_DEFINITION, ros_type, item["definition"])
        return self._schema_keys.get(kind)

    def mapped(self, rule: Rule, fields: dict[str, Any], when: datetime | None) -> list[Item]:
        """The events of a mapped message; ``when``: its header stamp, else when it was received."""
        if rule.event == "localisation":
            body = validate_body(EventType.LOCALISATION, localisation_body(fields, rule.pose))
            self._last_pose = body.pose.model_dump(mode="json")  # type: ignore[attr-defined]
            return [(EventType.LOCALISATION, body)]
        if rule.event == "map":
            pgm, metadata = occupancy_grid_map(fields)
            return [(t, validate_body(t, b)) for t, b in map_events(pgm, metadata, when)]
        frame = (fields.get("header") or {}).get("frame_id") or "map"
        body = hazard_body(fields, rule.description, rule.pose, self._last_pose, frame, when or now())
        return [(EventType.HAZARD, validate_body(EventType.HAZARD, body))]

    def forward(self, batch: list[dict[str, Any]]) -> None:
        """Rate limit, convert and put one batch in the outbox (one write)."""
        converted: list[Converted] = []
        for item in batch:
            topic = item["topic"]
            if not self._rate.allows(topic, item["received_ns"] / 1e9):
                self.counters.drop(topic, DropReason.RATE)
                continue
            try:
                events = self.events_of(item)
            except Exception as error:  # (ConversionError, SchemaError...): one message, not the writer
                self.counters.drop(topic, DropReason.UNREADABLE)
                log.warning("%s (%s) not forwarded: %s", topic, item.get("type"), error)
                continue
            over = next(byte_arrays(item["fields"], TRUNCATED_KEY), None) is not None
            converted.append(Converted(topic, events, over))
        if not converted:
            return
        try:
            self._publish(converted)
        except OutboxFull as error:
            # chunks reach their outbox limit long before small messages do: those go on alone
            large, small = [c for c in converted if c.blobs], [c for c in converted if not c.blobs]
            if not large or not small:
                self._outbox_full(converted, error)
                return
            self._outbox_full(large, error)
            try:
                self._publish(small)
            except OutboxFull as again:
                self._outbox_full(small, again)

    def _publish(self, converted: list[Converted]) -> None:
        """Into the outbox in one write, and counted; raises OutboxFull having taken none."""
        events = [event for message in converted for event in message.events]
        try:
            self.robot.publish_many(events, wait=False)
        except OutboxWriteFailed as error:
            self._keep(error)
        for message in converted:
            self.counters.recorded[message.topic] += 1
            if message.mapped:
                self.counters.mapped[message.topic] += 1
            if message.blobs:
                self.counters.blobs[message.topic] += message.blobs
            if message.over_bound:
                self.counters.over_bound[message.topic] += 1

    def _outbox_full(self, converted: list[Converted], error: OutboxFull) -> None:
        for message in converted:
            self.counters.drop(message.topic, DropReason.OUTBOX_FULL)
        log.error("the outbox is full: %d messages dropped (%s)", len(converted), error)

    # notifications to ROS
    def _notify(self) -> None:
        while not self._stop.is_set():
            try:
                for note in self.robot.notifications(stop=self._stop):
                    self.send_to_ros(notification_messages(note, NOTIFY_PREFIX))
                    self.counters.notifications += 1
                    if self._stop.is_set():
                        break
            except (PublisherError, pika.exceptions.AMQPError) as error:
                log.warning("notifications: %s; trying again", error)
                self._stop.wait(1.0)  # the client reconnects at the next call

    # the loop
    def run(self) -> int:
        """Forward until :meth:`stop` (0), restarting whatever part fails; 1 when the bridge cannot
        go on (why: in the status file, ``ended``). RosSideError when the ROS side cannot start at all."""
        parts = self.counters.parts
        self.start_ros_side()
        parts.started(WRITER_PART)
        threads = [supervised(NOTIFICATIONS_PART, self._notify, parts, self._stop)]
        if self.commands_url:
            url, robot = self.commands_url, self.robot.robot_id
            follow = lambda: follow_commands(url, robot, NOTIFY_PREFIX, self.send_to_ros, self._stop)  # noqa: E731
            threads.append(supervised(COMMANDS_PART, follow, parts, self._stop))
        next_status = time.monotonic() + self.options.status_every_s
        code = 0
        try:
            while not self._stop.is_set():
                batch = self._take()
                if batch:
                    self._write(batch)
                elif self._ended.is_set():
                    self._restart_ros_side()  # everything the last one wrote is forwarded
                if time.monotonic() >= next_status:
                    self.report()
                    next_status = time.monotonic() + self.options.status_every_s
        except Exception as error:
            log.exception("the ROS bridge cannot go on")
            self.counters.ended = f"{type(error).__name__}: {error}"
            code = 1
        finally:
            self._stop.set()
            self._end_ros_side()
            if code == 0:
                self._forward_the_rest()
            for thread in threads:
                thread.join(10)
            self.counters.parts.stopped(ROS_SIDE_PART)
            self.counters.parts.stopped(WRITER_PART)
            self._side_log.close()
            self.report()
        return code

    def _forward_the_rest(self) -> None:
        """At a stop, what the ROS side sent before it ended (it sends what it received once its
        input closes) goes to the outbox, not lost with the bridge's memory."""
        self._ended.wait(END_READ_S)
        while batch := self._take(draining=True):
            try:
                self._write(batch)
            except Exception:  # counted as write-failed by _write
                log.exception("the ROS bridge could not forward its last messages")
                return

    def _restart_ros_side(self) -> None:
        """The ROS side ended by itself (killed, or one of its threads failed): start it again
        after a backoff, which grows while it keeps failing; each try is noted in the status."""
        status = self._end_ros_side()
        detail = self._side_failure or f"it ended by itself (status {status}); see {self.ros_log}"
        delay = self.counters.parts.failed(ROS_SIDE_PART, detail)
        self.counters.ros_side = f"restarting in {delay:.1f} s: {detail}"
        self.report()
        if self._stop.wait(delay):
            return
        try:
            self.start_ros_side()
        except RosSideError as error:  # self._ended is set: the next round tries again
            self._side_failure = str(error)

    def _keep(self, error: OutboxWriteFailed) -> None:
        """Put in the outbox the events a failed write did not keep (a full disk), tried again after
        a backoff until it has room: the same events, with their numbers, never built again, since
        the first part is kept and the broker may have the rest (it keeps one copy of each).
        Stopped while it still fails, raise the error (:meth:`_write` counts the batch dropped)."""
        parts = self.counters.parts
        while True:
            if self._stop.wait(parts.failed(WRITER_PART, f"{type(error).__name__}: {error}")):
                raise error
            try:
                self.robot.enqueue(error.not_kept, wait=False)
                return
            except OutboxWriteFailed as again:
                error = again

    def _write(self, batch: list[dict[str, Any]]) -> None:
        """Forward ``batch``, again after a backoff while the outbox cannot be written (a full
        disk): the batch waits, it is not lost. Stopped while it still fails, its messages are
        counted as dropped (``write-failed``) and the error raised: the bridge ends with 1."""
        parts = self.counters.parts
        while True:
            try:
                self.forward(batch)
            except Exception as error:
                detail = f"{type(error).__name__}: {error}"
                if self._stop.wait(parts.failed(WRITER_PART, detail)):
                    for item in batch:
                        self.counters.drop(item["topic"], DropReason.WRITE_FAILED)
                    raise
                continue
            if WRITER_PART in parts.failing():
                parts.started(WRITER_PART)
            return

    def _take(self, draining: bool = False) -> list[dict[str, Any]]:
        """The next batch (up to BATCH): what the ROS side sent as one, which it gathered for
        ``linger_s`` from its first message, so that a steady topic costs one outbox write a linger,
        not one a message (a message of a mapped topic ends a batch at once). Waiting for the
        batch's end wakes this thread once a batch, not once a message; a linger after the first
        message's receipt ends the wait if the end does not come. ``draining``: what is held now,
        without waiting."""
        try:
            batch = [self._queue.get(timeout=0.0 if draining else STOP_CHECK_S)]
        except queue.Empty:
            return []
        if not draining:
            waited = max(0.0, time.time() - batch[0]["received_ns"] / 1e9)
            deadline = time.monotonic() + max(0.0, self.options.linger_s - waited) + STOP_CHECK_S
            while not self._batch_ended.wait(max(0.0, min(STOP_CHECK_S, deadline - time.monotonic()))):
                if time.monotonic() >= deadline or self._stop.is_set():
                    break
        self._batch_ended.clear()  # a batch that ends while these are taken is taken next, at once
        while len(batch) < BATCH:
            try:
                batch.append(self._queue.get(timeout=0.0))
            except queue.Empty:
                break
        return batch

    def report(self) -> None:
        outbox = self.robot.outbox
        self.counters.broker = {
            "connected": self.robot.connected,
            "last_error": self.robot.last_error,
            # what waits for the broker, what the outbox's bounds dropped and the broker refused, by
            # type: the bridge's robot sends no status, so `fleetbus team` cannot show them
            "outbox": {
                "waiting": dict(outbox.counts()),
                "dropped": dict(outbox.dropped()),
                "refused": dict(outbox.refused_counts()),
            },
        }
        self.counters.write(self.status_file)
        log.info("ROS bridge: %s", self.counters.status_line())

    def stop(self) -> None:
        self._stop.set()

    def _end_ros_side(self) -> int:
        process = self._process
        if process is None:
            return 0
        if process.stdin is not None:
            with self._stdin_lock:
                try:
                    process.stdin.close()  # the ROS side ends at the end of its input
                except BrokenPipeError:
                    pass
        try:
            code = process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            code = process.wait()
        if self._log_copy is not None:  # its last lines in the file before its end is reported
            self._log_copy.join(END_READ_S)
        self.counters.ros_side = f"ended ({code})"
        return code
