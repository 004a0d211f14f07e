"""The ROS side of ``fleetbus ros bridge``: a plain script for the ROS machine's own Python.

It imports rospy and nothing of fleetbus, so it runs on the interpreter ROS is installed for
(Debian's ``/usr/bin/python3``) while fleetbus runs in its own environment. The two talk in JSON
lines over this process's standard streams:

stdout, one object a line (``kind`` says which):
  ``started``     rospy is imported: the process can run here
  ``master``      ``state`` (``running``, ``unreachable``), ``detail``, ``retry_in`` (s), ``restarted``:
                  how the master answers; every failure is retried, backing off up to a limit
  ``ready``       the node is up (registered with a master)
  ``subscribed``  ``topic``, ``type``: a topic found and subscribed to
  ``message``     ``topic``, ``type``, ``md5sum``, ``stamp_ns`` (the header's stamp in ns, or null),
                  ``received_ns`` (UNIX time in ns), ``fields`` (the message as a document, see
                  :func:`to_document`); the first of each topic and type also ``definition`` (the
                  type's full definition, as its publisher sent it); a message with byte arrays
                  over ``--raw-from`` bytes also ``raw``, their lengths: the arrays follow the
                  line, as they are, in that order
  ``batch-end``   the messages before it are a batch (one linger's, or up to an urgent one)
  ``dropped``     ``counts``: {topic: messages dropped here since the last report} (queue full)
  ``error``       ``topic``, ``detail``: a message that could not be read
  ``failed``      ``part``, ``detail``: one of its threads failed, or ended while the process was not
                  stopping (its node was shut down from outside: ``rosnode kill``); the process
                  ends (status 70) and the bridge starts it again
stdin, one object a line:
  ``publish``     ``topic``, ``type``, ``fields``: publish this message (latched) on the ROS side

Message lines go out together: the messages received within ``--linger`` seconds of the first are
read into fields and sent in one write (the bridge's reader wakes once for them, and the reader
here once for them, not once a message); a message of an ``--urgent`` topic (one a mapping rule
names), or a batch that fills the pipe's buffer (an image), sends what is held at once.

The process ends when its standard input closes (the bridge ended), having sent what it received,
or with the bridge itself (the kernel signals it when its parent dies), and its end closes its
stdout. It waits for a
master that is not there yet, and when the master comes back after a restart it registers its
subscriptions and publications with the new one (ROS 1 nodes do not do that by themselves).
"""

from __future__ import annotations

import argparse
import base64
import ctypes
import fnmatch
import hashlib
import json
import math
import os
import queue
import signal
import sys
import threading
import time
import xmlrpc.client
from collections.abc import Iterable
from itertools import chain
from typing import Any, NoReturn

import genpy
import genpy.dynamic
import genpy.message
import rosgraph.masterapi
import roslib.message
import rospy
import rospy.impl.registration
from held import HeldQueue  # beside this file: the script's folder is first on its path

#: The most messages the reader sends in one batch.
HELD_LINES = 256
#: The line after a batch's messages: the bridge takes the batch whole.
BATCH_END = {"kind": "batch-end"}
#: The pipe's buffer: a batch of small lines goes in one write, and one of this many bytes (an
#: image) without waiting for the linger, so that large messages are not held in memory.
PIPE_BUFFER = 1 << 16
#: How often the reader looks whether the bridge closed its input, while it waits.
CHECK_S = 0.5
#: Array types kept as bytes (``{"_base64": ..., "length": n}``), as fleetbus keeps imported bags.
BYTE_ARRAYS = ("uint8[", "int8[", "char[", "byte[")
BYTES_KEY, TRUNCATED_KEY, RAW_KEY = "_base64", "_truncated", "_raw"  # as fleetbus.schemas.ros names them


class RawArrays:
    """The byte arrays of one message over ``least`` bytes: sent as they are after its line, not
    in base64 inside it (an image would be encoded here and decoded in the bridge)."""

    def __init__(self, least: int) -> None:
        self.least = least
        self.arrays: list[bytes] = []

    def take(self, data: bytes) -> dict[str, Any] | None:
        if len(data) <= self.least:
            return None
        self.arrays.append(data)
        return {RAW_KEY: len(self.arrays) - 1, "length": len(data)}


def to_document(value: Any, bytes_max: int, slot_type: str = "", raw: RawArrays | None = None) -> Any:
    """A genpy message (or field value) as plain JSON, in fleetbus's convention for ROS messages
    (``fleetbus.schemas.ros``): nested messages as objects, times as ``{"sec", "nanosec"}``, byte
    arrays as ``{"_base64", "length"}`` (over ``raw.least``, ``{"_raw": i, "length"}``, the bytes
    in ``raw``) or, over ``bytes_max``, ``{"_truncated", "length", "sha256"}``, floats JSON cannot
    hold as ``"nan"``, ``"inf"``, ``"-inf"``."""
    if isinstance(value, genpy.Message):
        return {
            slot: to_document(getattr(value, slot), bytes_max, kind, raw)
            for slot, kind in zip(value.__slots__, value._slot_types, strict=True)
        }
    if isinstance(value, (genpy.Time, genpy.Duration)):
        return {"sec": value.secs, "nanosec": value.nsecs}
    if isinstance(value, (bytes, bytearray)) or (
        slot_type.startswith(BYTE_ARRAYS) and isinstance(value, (list, tuple))
    ):
        data = bytes(value) if isinstance(value, (bytes, bytearray)) else bytes(v & 0xFF for v in value)
        if len(data) > bytes_max:
            return {TRUNCATED_KEY: True, "length": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        kept = raw.take(data) if raw is not None else None
        return kept or {BYTES_KEY: base64.b64encode(data).decode("ascii"), "length": len(data)}
    if isinstance(value, (list, tuple)):
        element = slot_type.split("[", 1)[0]
        return [to_document(item, bytes_max, element, raw) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def header_stamp(msg: Any) -> int | None:
    """The header stamp in nanoseconds, when the message has a header with a non-zero stamp."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if isinstance(stamp, genpy.Time) and (stamp.secs or stamp.nsecs):
        return stamp.secs * 1_000_000_000 + stamp.nsecs
    return None


class Output:
    """Everything written to stdout, one JSON line at a time, from any thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # a buffer that takes a batch of small lines whole: the bridge's reader wakes once for them
        self._stream = open(sys.stdout.fileno(), "wb", buffering=PIPE_BUFFER, closefd=False)

    def write(self, item: dict[str, Any]) -> None:
        self.write_all([item])

    def write_all(self, items: Iterable[dict[str, Any]]) -> None:
        """``items`` one line each, then flushed: one write to the pipe for a batch of small ones.
        They are made one at a time, so a batch of images is never whole in memory. A message's
        ``raw`` arrays follow its line as they are, the line saying their lengths."""
        with self._lock:
            try:
                for item in items:
                    arrays: list[bytes] = item.pop("raw", None) or []
                    if arrays:
                        item["raw"] = [len(array) for array in arrays]
                    self._stream.write(json.dumps(item, separators=(",", ":")).encode() + b"\n")
                    for array in arrays:
                        self._stream.write(array)
                self._stream.flush()
            except (BrokenPipeError, ValueError):
                rospy.signal_shutdown("the bridge closed the pipe")


class Recorder:
    """Subscribes to topics and hands their messages, read, to the output; never blocks ROS."""

    def __init__(self, out: Output, args: argparse.Namespace) -> None:
        self.out = out
        self.args = args
        self.queue: HeldQueue[tuple[str, Any, int]] = HeldQueue(args.queue, args.queue_bytes)
        self.subscribed: dict[str, rospy.Subscriber] = {}
        self.dropped: dict[str, int] = {}
        self.dropped_lock = threading.Lock()
        self.classes: dict[tuple[str, str], type] = {}
        self.defined: set[tuple[str, str]] = set()
        self.closing = threading.Event()
        """Set when the bridge closed our input: what was received is sent, then the reader ends."""
        self.converting = threading.Event()
        self.flushed = threading.Event()
        self.woken = threading.Event()
        """Set by an urgent message, a batch of ``PIPE_BUFFER`` bytes or ``closing``: what is held
        goes at once."""
        self.urgent_topics: dict[str, bool] = {}

    def wanted(self, topic: str) -> bool:
        if topic.startswith(self.args.own_prefix + "/") or topic == self.args.own_prefix:
            return False  # what this node publishes for fleetbus is not recorded back
        if self.args.include and not any(fnmatch.fnmatchcase(topic, p) for p in self.args.include):
            return False
        return not any(fnmatch.fnmatchcase(topic, p) for p in self.args.exclude)

    def discover(self, master: rosgraph.masterapi.Master) -> None:
        for topic, type_name in master.getPublishedTopics(""):
            if topic not in self.subscribed and self.wanted(topic):
                self.subscribed[topic] = rospy.Subscriber(
                    topic, rospy.AnyMsg, self.received, callback_args=topic, queue_size=None
                )
                self.out.write({"kind": "subscribed", "topic": topic, "type": type_name})

    def received(self, raw: Any, topic: str) -> None:
        if not self.queue.offer((topic, raw, time.time_ns()), len(raw._buff)):
            with self.dropped_lock:
                self.dropped[topic] = self.dropped.get(topic, 0) + 1
        elif self.urgent(topic) or self.queue.held_bytes >= PIPE_BUFFER:
            self.woken.set()  # an urgent message, or a batch that fills the pipe: no linger

    def message_class(self, raw: Any) -> type:
        header = raw._connection_header
        key = (header["type"], header.get("md5sum", ""))
        cls = self.classes.get(key)
        if cls is None:
            cls = roslib.message.get_message_class(header["type"])
            if cls is None or cls._md5sum != header.get("md5sum", cls._md5sum):
                # a type this machine has no package for (or another version): from its definition
                cls = genpy.dynamic.generate_dynamic(header["type"], header["message_definition"])[
                    header["type"]
                ]
            self.classes[key] = cls
        return cls

    def urgent(self, topic: str) -> bool:
        found = self.urgent_topics.get(topic)
        if found is None:
            found = self.urgent_topics[topic] = any(fnmatch.fnmatchcase(topic, p) for p in self.args.urgent)
        return found

    def convert_forever(self) -> None:
        """From a batch's first message, wait for the linger (or an urgent message: one of a topic
        a mapping rule names, ``--urgent``), then read every message held into its line and send
        them in one write: the thread wakes once a batch, not once a message. Once ``closing``,
        what is held is sent, and the reader ends."""
        self.converting.set()
        while not rospy.is_shutdown():
            closing = self.closing.is_set()
            try:
                first = self.queue.get(timeout=0.0 if closing else CHECK_S)
            except queue.Empty:
                if closing:
                    break
                continue
            due = time.monotonic() + self.args.linger
            while not self.woken.wait(min(CHECK_S, max(0.0, due - time.monotonic()))):
                if time.monotonic() >= due or rospy.is_shutdown():
                    break
            self.woken.clear()  # an urgent message held after this wakes the next batch at once
            batch = [first]
            while len(batch) < HELD_LINES:
                try:
                    batch.append(self.queue.get(timeout=0.0))
                except queue.Empty:
                    break
            self.out.write_all(chain((self.convert(*held) for held in batch), [BATCH_END]))
        self.flushed.set()

    def close(self, timeout: float) -> None:
        """Have the reader send what was received (when it runs), waiting ``timeout`` at most."""
        self.closing.set()
        self.woken.set()
        if self.converting.is_set():
            self.flushed.wait(timeout)

    def convert(self, topic: str, raw: Any, received: int) -> dict[str, Any]:
        """The message's line: a ``message``, or an ``error`` when it cannot be read."""
        try:
            type_name = raw._connection_header["type"]
            msg = self.message_class(raw)().deserialize(raw._buff)
            arrays = RawArrays(self.args.raw_from)
            fields = to_document(msg, self.args.bytes_max, raw=arrays)
        except Exception as error:  # a message that cannot be read is reported, not fatal
            return {"kind": "error", "topic": topic, "detail": repr(error)}
        item = {
            "kind": "message",
            "topic": topic,
            "type": type_name,
            "md5sum": raw._connection_header.get("md5sum"),
            "stamp_ns": header_stamp(msg),
            "received_ns": received,
            "fields": fields,
        }
        if arrays.arrays:
            item["raw"] = arrays.arrays
        if (topic, item["md5sum"]) not in self.defined:  # the first of its kind says its definition
            self.defined.add((topic, item["md5sum"]))
            item["definition"] = raw._connection_header.get("message_definition")
        return item

    def report_drops(self) -> None:
        with self.dropped_lock:
            counts, self.dropped = self.dropped, {}
        if counts:
            self.out.write({"kind": "dropped", "counts": counts})


class Publishers:
    """The ROS topics fleetbus writes to, made on first use (latched: a late subscriber gets the
    last). What comes before the node is up waits, the newest per topic, and goes out once it is."""

    def __init__(self, out: Output) -> None:
        self.out = out
        self.publishers: dict[str, rospy.Publisher] = {}
        self.waiting: dict[str, dict[str, Any]] = {}
        self.started = False
        self._lock = threading.Lock()

    def start(self) -> None:
        with self._lock:
            self.started = True
            waiting, self.waiting = self.waiting, {}
        for item in waiting.values():
            self.publish(item)

    def publish(self, item: dict[str, Any]) -> None:
        with self._lock:
            if not self.started:
                self.waiting[item["topic"]] = item  # latched topics: only the last one counts
                return
        topic, type_name = item["topic"], item["type"]
        cls = roslib.message.get_message_class(type_name)
        if cls is None:
            self.out.write({"kind": "error", "topic": topic, "detail": f"no message type {type_name}"})
            return
        publisher = self.publishers.get(topic)
        if publisher is None:
            publisher = rospy.Publisher(topic, cls, queue_size=100, latch=True)
            self.publishers[topic] = publisher
        msg = cls()
        genpy.message.fill_message_args(msg, [item["fields"]])
        publisher.publish(msg)


FAILED_STATUS = 70  # EX_SOFTWARE
#: How long the ROS side takes at most, once its input is closed, to send what it received.
CLOSE_TIMEOUT_S = 5.0
#: Held by the thread that ends the process: the first part to fail is the one reported.
LEAVING = threading.Lock()
#: Why rospy shut the node down (``rosnode kill``: an external request), once it did.
SHUT_DOWN_BECAUSE: list[str] = []


def fail(out: Output, part: str, detail: str) -> NoReturn:
    """Say that ``part`` failed, leave the master and end the process: the bridge starts it again."""
    LEAVING.acquire()  # never released: a second failing part waits here for the end
    out.write({"kind": "failed", "part": part, "detail": detail})
    leaving = threading.Thread(target=rospy.signal_shutdown, args=(f"{part} failed",), daemon=True)
    leaving.start()  # unregister from the master, if it answers soon
    leaving.join(2.0)
    os._exit(FAILED_STATUS)


def why_it_returned() -> str:
    if not rospy.is_shutdown():
        return "it ended while the node runs"
    because = SHUT_DOWN_BECAUSE[0] if SHUT_DOWN_BECAUSE else "no reason given"
    return f"the ROS node was shut down ({because})"


def guarded(out: Output, part: str, stopping: threading.Event, target: Any, *args: Any) -> threading.Thread:
    """A daemon thread running ``target(*args)``; should it raise, or return while the process is
    not ``stopping``, the process says so and ends (the bridge starts it again): never a process
    with one of its threads gone. A master's ``shutdown`` call (``rosnode kill``) shuts rospy down
    with no error: the threads return, and the main thread, reading our input, would go on."""

    def run() -> None:
        try:
            target(*args)
        except BaseException as error:
            fail(out, part, f"{type(error).__name__}: {error}")
        if not stopping.is_set():
            fail(out, part, why_it_returned())

    thread = threading.Thread(target=run, name=part, daemon=True)
    thread.start()
    return thread


def every(seconds: float, action: Any) -> None:
    while not rospy.is_shutdown():
        action()
        time.sleep(seconds)  # a period, not a wait for a condition


class MasterWatch:
    """Asks the master, retries every failure with backoff, says how it goes, and registers this
    node again with a master that restarted (a new process: another pid)."""

    def __init__(self, out: Output, every_s: float, most_s: float) -> None:
        self.out, self.every_s, self.most_s = out, every_s, most_s
        self.master = rosgraph.masterapi.Master(rospy.names.get_caller_id())
        self.pid: int | None = None
        self.state = ""
        self.failures = 0

    def delay(self) -> float:
        return min(self.every_s * 2 ** min(self.failures, 16), self.most_s) if self.failures else self.every_s

    def answers(self) -> int | None:
        """The master's pid, or None (reported, with when the next try is) when it does not answer."""
        try:
            pid = int(self.master.getPid())
        except Exception as error:  # socket errors, refusals: all mean "not now"
            self.failures += 1
            self.report("unreachable", f"{type(error).__name__}: {error}")
            return None
        restarted = self.pid is not None and pid != self.pid
        self.pid, self.failures = pid, 0
        if restarted or self.state != "running":
            self.report("running", "", restarted=restarted)
        return pid

    def report(self, state: str, detail: str, restarted: bool = False) -> None:
        self.state = state
        item = {"kind": "master", "state": state, "detail": detail, "uri": self.master.master_uri}
        self.out.write({**item, "retry_in": self.delay() if detail else None, "restarted": restarted})

    def register_again(self) -> None:
        """This node's publications and subscriptions, registered with the (new) master; each
        subscription is told of the topic's publishers, as the master would tell it."""
        manager = rospy.impl.registration.get_topic_manager()
        uri = rospy.get_node_uri()
        for topic, type_name in manager.get_publications():
            self.master.registerPublisher(topic, type_name, uri)
        for topic, type_name in manager.get_subscriptions():
            publishers = self.master.registerSubscriber(topic, type_name, uri)
            xmlrpc.client.ServerProxy(uri).publisherUpdate("/master", topic, publishers)

    def wait(self, ended: threading.Event) -> bool:
        """Until the master answers (True), or ``ended`` is set (False)."""
        while self.answers() is None:
            if ended.wait(self.delay()):
                return False
        return True

    def watch(self, recorder: Recorder) -> None:
        """Discovery, for as long as the node runs: new topics, a master gone, a master back."""
        while not rospy.is_shutdown():
            before = self.pid
            pid = self.answers()
            try:
                if pid is not None and before is not None and pid != before:
                    self.register_again()
                if pid is not None:
                    recorder.discover(self.master)
            except Exception as error:  # the master went away half-way: the next round retries
                self.failures += 1
                self.report("unreachable", f"{type(error).__name__}: {error}")
                if before is not None and pid != before:
                    self.pid = before  # register again at the next round
            time.sleep(self.delay())  # a period (or backoff), not a wait for a condition


def end_with_parent(parent: int | None) -> None:
    """Ask the kernel to end this process when the bridge that started it (``parent``) dies
    (Linux); end now if it died before we asked."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # another system: the end of our input still ends us
    if parent is not None and os.getppid() != parent:
        sys.exit("the bridge that started this process is gone")


def start_node(
    args: argparse.Namespace, out: Output, recorder: Recorder, publishers: Publishers, ended: threading.Event
) -> None:
    """Waits for the master, starts the node, then discovers for ever (a thread of its own)."""
    watch = MasterWatch(out, args.discover_every, args.retry_most)
    if not watch.wait(ended):
        return
    rospy.init_node(args.node, anonymous=True, disable_signals=True)
    rospy.core.add_preshutdown_hook(SHUT_DOWN_BECAUSE.append)
    watch.master = rosgraph.masterapi.Master(rospy.get_name())
    guarded(out, "drop counter", ended, every, 1.0, recorder.report_drops)
    guarded(out, "reader", ended, recorder.convert_forever)
    publishers.start()
    out.write({"kind": "ready"})
    watch.watch(recorder)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--node", default="fleetbus_bridge")
    parser.add_argument("--discover-every", type=float, default=1.0)
    parser.add_argument("--retry-most", type=float, default=10.0, help="longest wait between tries")
    parser.add_argument("--include", action="append", default=[])
    parser.add_argument("--exclude", action="append", default=[])
    parser.add_argument("--bytes-max", type=int, default=16 * 1024 * 1024)  # FLEETBUS_ROS_BLOB_MAX_BYTES
    parser.add_argument("--raw-from", type=int, default=64 * 1024, help="byte arrays sent beside their line")
    parser.add_argument("--queue", type=int, default=10_000)
    parser.add_argument("--queue-bytes", type=int, default=64 * 1024 * 1024)
    parser.add_argument("--own-prefix", default="/fleetbus")
    parser.add_argument("--linger", type=float, default=0.0, help="seconds a line may wait for others")
    parser.add_argument("--urgent", action="append", default=[], help="a topic pattern sent at once")
    parser.add_argument("--parent", type=int, help="the bridge's pid: this process ends with it")
    args = parser.parse_args()

    end_with_parent(args.parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the bridge, which closes our input
    out = Output()
    sys.stdout = sys.stderr  # rospy prints (a shutdown request): to the log, not among our lines
    out.write({"kind": "started"})
    ended = threading.Event()  # the bridge closed our input: the process stops, its threads may end
    recorder, publishers = Recorder(out, args), Publishers(out)
    guarded(out, "discovery", ended, start_node, args, out, recorder, publishers, ended)
    for line in sys.stdin:  # ends when the bridge closes our stdin (or dies)
        try:
            item = json.loads(line)
            if item.get("kind") == "publish":
                publishers.publish(item)
        except Exception as error:  # a bad request is reported, the node goes on
            out.write(
                {"kind": "error", "topic": "", "detail": f"cannot publish {line.strip()[:200]}: {error!r}"}
            )
    ended.set()
    recorder.close(CLOSE_TIMEOUT_S)  # what was received goes to the bridge, which reads to the end
    recorder.report_drops()  # the last counts, before the pipe closes
    if publishers.started:
        rospy.signal_shutdown("the bridge closed its end")


if __name__ == "__main__":
    main()
