"""The recorder against the real broker: every message stored as received, with its provenance."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from urllib.parse import urlsplit

import pika
import pika.exceptions
import pytest

from fleetbus.broker.accounts import RECORDER_USER, url_for
from fleetbus.limits import parse_retention
from fleetbus.processes import pid_alive
from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.routing import INGEST_EXCHANGE, INGEST_QUEUE, RECORDER_QUEUE, EventType, RobotKind
from fleetbus.workers.recorder.capture import refusal
from fleetbus.workers.recorder.filters import RoutingFilter
from fleetbus.workers.recorder.process import PARENT_ENV, recorder_environment
from fleetbus.workers.store import open_recording_store
from fleetbus.workers.store.base import WriteResult
from fleetbus.workers.store.recordings import Condition, Op, RecordedMessage, RecordingStore
from tests.factories import hazard, status
from tests.support import PROJECT_ROOT, Bus, wait_for
from tests.test_cli import fleetbus

TF = {
    "frame": "/kinect/depth",
    "child_frame": "/object/bottle",
    "translation": {"x": 0.1, "y": 0.2, "z": 0.3},
}


def test_every_message_is_recorded_as_received_with_its_provenance(stored_bus: Bus) -> None:
    bus = stored_bus
    explorer = bus.add("rec-explorer", kind=RobotKind.EXPLORER)
    warden = bus.add("rec-warden", kind=RobotKind.WARDEN)  # hazards are announced to a warden or held
    with bus.worker(), bus.recorder(), bus.robot(explorer) as robot, bus.robot(warden) as guard:
        guard.publish(EventType.LOCALISATION, {"localised": True})
        sent = robot.publish(EventType.HAZARD, hazard())
        robot.publish(EventType.STATUS, status())
        bus.publish_raw(explorer, "rec-explorer.tf", json.dumps(TF).encode(), message_id="tf-1")
        bus.publish_raw(explorer, "rec-explorer.camera.raw", b"\x89PNG\x00\xff")
        wait_for(
            lambda: len(bus.recorded("dead_letter")) == 2,
            what="both unknown types dead-lettered and recorded",
        )
        wait_for(lambda: bus.recorded("notification"), what="the hazard's notification recorded")

    [recorded] = bus.recorded("hazard")
    assert recorded.known and recorded.problem is None
    assert (recorded.user_id, recorded.robot_id) == ("rec-explorer", "rec-explorer")
    assert (recorded.exchange, recorded.routing_key) == ("rec-explorer.events", "rec-explorer.hazard")
    assert recorded.message_id == str(sent.message_id) and recorded.seq == sent.seq
    assert recorded.sent_at == sent.sent_at and recorded.recorded_at >= sent.sent_at
    assert recorded.document == json.loads(sent.model_dump_json()), "the envelope, field for field"
    assert recorded.properties["delivery_mode"] == 2 and recorded.properties["message_id"] == str(
        sent.message_id
    )

    [tf] = bus.recorded("tf")
    assert not tf.known and tf.document == TF and tf.message_id == "tf-1"
    assert tf.routing_key == "rec-explorer.tf" and tf.user_id == "rec-explorer"

    [camera] = bus.recorded("camera")
    assert camera.routing_key == "rec-explorer.camera.raw" and camera.raw == b"\x89PNG\x00\xff"
    assert camera.document is None and "not JSON" in (camera.problem or "")

    [note] = bus.recorded("notification")
    assert note.user_id == "fleetbus" and note.routing_key == "notify.hazard"
    assert note.message_id == f"{sent.message_id}:hazard" and note.document["hazard_id"] == 1
    assert note.properties["headers"]["x-fleetbus-announced-to"] == ["rec-warden"], "who took it"

    refused = {r.routing_key: r for r in bus.recorded("dead_letter")}
    assert set(refused) == {"rec-explorer.tf", "rec-explorer.camera.raw"}
    letter = refused["rec-explorer.tf"]
    assert letter.robot_id == "rec-explorer" and letter.document == TF
    assert refusal(letter) == (
        "unknown-type",
        "routing key 'rec-explorer.tf' names unknown type 'tf'; known: "
        + ", ".join(t.value for t in EventType),
    ), "the worker's reason, from the store: the broker moved the message unchanged"
    assert len(bus.recorded("status")) == 1


def test_new_robots_and_types_are_recorded_without_a_restart(bus: Bus) -> None:
    with bus.recorder() as recorder:
        late = bus.add("rec-late", kind=RobotKind.WARDEN)
        bus.publish_raw(late, "rec-late.joint_state", b'{"position": [0.1, 0.2]}')
        bus.publish_raw(late, "rec-late.joint_state", b'{"position": [0.3, 0.4]}')
        wait_for(lambda: len(bus.recorded("joint_state")) == 2, what="a type first seen after the start")
        # the recorder counts a batch after its write: the store shows it first
        wait_for(lambda: recorder.stats().by_type == {"joint_state": 2}, what="both counted as joint_state")
    positions = [r.document["position"] for r in bus.recorded("joint_state")]
    assert positions == [[0.1, 0.2], [0.3, 0.4]]


def test_include_and_exclude_patterns(bus: Bus) -> None:
    one, two = bus.add("rec-one"), bus.add("rec-two")
    keep = RoutingFilter(include=("rec-one.#",), exclude=("*.status",))
    with bus.recorder(filter=keep) as recorder:
        for account in (one, two):
            with bus.robot(account) as robot:
                robot.publish(EventType.STATUS, status())
                robot.publish(EventType.HAZARD, hazard())
        wait_for(lambda: recorder.stats().filtered == 3, what="three messages left out")
        wait_for(lambda: bus.recorded("hazard"), what="rec-one's hazard")
    assert [r.robot_id for r in bus.recorded("hazard")] == ["rec-one"]
    assert bus.recorded("status") == []


def test_a_message_delivered_twice_is_recorded_once(bus: Bus) -> None:
    robot = bus.add("rec-twice")
    with bus.recorder() as recorder:
        for _ in range(2):
            bus.publish_raw(robot, "rec-twice.tf", b'{"a": 1}', message_id="same-id")
            bus.publish_raw(robot, "rec-twice.tf", b'{"no": "id"}')
        bus.publish_raw(robot, "rec-twice.tf", b'{"no": "id, other body"}')
        wait_for(lambda: recorder.stats().recorded + recorder.stats().duplicates == 5, what="all five seen")
        assert (recorder.stats().recorded, recorder.stats().duplicates) == (3, 2)
    assert len(bus.recorded("tf")) == 3


def test_what_arrives_while_the_recorder_is_down_is_recorded_when_it_is_back(bus: Bus) -> None:
    robot = bus.add("rec-backlog")
    with bus.recorder():
        pass  # declares the recorder's queue and bindings
    with bus.robot(robot) as client:
        client.publish_many([(EventType.STATUS, status(float(i))) for i in range(50)])
    assert bus.recorded("status") == []
    with bus.recorder():
        wait_for(lambda: len(bus.recorded("status")) == 50, what="the backlog recorded")
    seqs = [r.seq for r in bus.recorded("status")]
    assert sorted(seqs) == list(range(50))


def test_retention_bounds_each_type_while_recording(bus: Bus) -> None:
    robot = bus.add("rec-bounded")
    policies = parse_retention(["status=5", "*=1GB"])

    def counted() -> list[tuple[str, int]]:
        shown = fleetbus(bus, "stats", "--json")
        assert shown.returncode == 0, shown.stderr
        rows = [json.loads(line) for line in shown.stdout.splitlines()]
        return [(r["subject"], r["count"]) for r in rows if r.get("bound") == "recording"]

    with bus.recorder(retention=policies, retention_interval=0.1) as recorder, bus.robot(robot) as client:
        client.publish_many([(EventType.STATUS, status(float(i))) for i in range(20)])
        client.publish(EventType.HAZARD, hazard())
        wait_for(lambda: recorder.stats().recorded == 21, what="all recorded")
        wait_for(lambda: len(bus.recorded("status")) == 5, what="status cut to its newest five")
        # what the recording's bound deleted, where an operator sees it
        wait_for(lambda: counted() == [("status", 15)], what="the deleted counted in fleetbus stats")
    assert [r.seq for r in bus.recorded("status")] == [15, 16, 17, 18, 19]
    assert len(bus.recorded("hazard")) == 1


def test_a_body_the_database_cannot_hold_is_kept_raw_and_recording_goes_on(stored_bus: Bus) -> None:
    bus = stored_bus
    robot = bus.add("rec-odd")
    huge = b'{"big": 123456789012345678901234567890}'
    with bus.recorder() as recorder:
        bus.publish_raw(robot, "rec-odd.tf", huge)
        bus.publish_raw(robot, "rec-odd.tf", b'{"fine": true}')
        wait_for(lambda: recorder.stats().recorded == 2, what="both recorded")
    odd, fine = bus.recorded("tf")
    assert fine.document == {"fine": True}
    if bus.settings.mongodb_url:  # BSON has no integer that large
        assert odd.raw == huge and "MongoDB" in (odd.problem or "")
    else:
        assert odd.document == {"big": 123456789012345678901234567890}


def test_a_timestamp_in_milliseconds_is_read_as_such_and_recording_goes_on(bus: Bus) -> None:
    """Some AMQP clients put milliseconds in the timestamp property: read as seconds it is past
    any date. The recorder failed on it, lost its connection, got it again first, and recorded
    nothing more."""
    robot = bus.add("rec-ms")
    with bus.recorder() as recorder:
        bus.publish_raw(robot, "rec-ms.tf", b'{"ms": true}', timestamp=1_767_225_600_000)
        bus.publish_raw(robot, "rec-ms.tf", b'{"after": true}')
        wait_for(lambda: recorder.stats().recorded == 2, what="both recorded")
    in_ms, after = bus.recorded("tf")
    assert in_ms.properties["timestamp"] == "2026-01-01T00:00:00+00:00"
    assert after.document == {"after": True}


def test_what_the_store_refuses_even_raw_is_dead_lettered_with_its_reason_and_counted(
    stored_bus: Bus, monkeypatch: pytest.MonkeyPatch
) -> None:
    bus = stored_bus
    robot = bus.add("rec-odd")
    store_class = type(open_recording_store(bus.settings))
    write = store_class.write_recorded

    async def refusing(self: RecordingStore, records: Sequence[RecordedMessage]) -> list[WriteResult]:
        if any(record.routing_key == "rec-odd.poison" for record in records):
            raise ValueError("the database refuses this one, whatever its form")
        return await write(self, records)

    monkeypatch.setattr(store_class, "write_recorded", refusing)
    with bus.recorder() as recorder:
        bus.publish_raw(robot, "rec-odd.tf", b'{"before": true}')
        bus.publish_raw(robot, "rec-odd.poison", b'{"odd": true}', message_id="poison-1")
        bus.publish_raw(robot, "rec-odd.tf", b'{"after": true}')
        [letter] = wait_for(lambda: bus.dead_letters(), what="the unstorable message dead-lettered")
        wait_for(lambda: recorder.stats().recorded == 2, what="the others recorded")
        assert recorder.stats().unstorable == 1
    assert (letter.message_id, letter.reason, letter.routing_key) == (
        "poison-1",
        "unstorable",
        "rec-odd.poison",
    )
    assert "the database refuses this one" in letter.detail
    assert [r.document for r in bus.recorded("tf")] == [{"before": True}, {"after": True}]
    shown = fleetbus(bus, "stats", "--since", "10m")
    assert shown.returncode == 0, shown.stderr
    assert "dead letters: 1 (unstorable 1)" in shown.stdout


def test_field_conditions_reach_recorded_documents(bus: Bus) -> None:
    robot = bus.add("rec-fields")
    with bus.recorder() as recorder:
        for i, frame in enumerate(("/a", "/b", "/a")):
            bus.publish_raw(robot, "rec-fields.tf", json.dumps({"frame": frame}).encode(), message_id=f"t{i}")
        wait_for(lambda: recorder.stats().recorded == 3, what="three transforms")
    assert len(bus.recorded("tf", conditions=(Condition("frame", Op.EQ, "/a"),))) == 2


def test_the_recorder_account_may_only_read_its_queue(bus: Bus) -> None:
    with bus.recorder():
        pass
    password = (bus.settings.accounts_dir / f"{RECORDER_USER}.password").read_text().strip()
    url = url_for(bus.admin_url, RECORDER_USER, password)

    def refused(action: str) -> None:
        connection = blocking_connection(url)
        channel = connection.channel()
        with pytest.raises(pika.exceptions.ChannelClosedByBroker) as error:
            if action == "publish":
                channel.confirm_delivery()
                channel.basic_publish(INGEST_EXCHANGE, "someone.hazard", b"{}", mandatory=True)
            elif action == "consume ingest":
                channel.basic_consume(INGEST_QUEUE, lambda *a: None)
            elif action == "declare":
                channel.queue_declare("fleetbus.recorder.mine")
            elif action == "bind":
                channel.queue_bind(RECORDER_QUEUE, "amq.topic", "#")
        assert error.value.reply_code == 403, action
        connection.close()

    for action in ("publish", "consume ingest", "declare", "bind"):
        refused(action)
    connection = blocking_connection(url)
    connection.channel().basic_consume(RECORDER_QUEUE, lambda *a: None)  # its own queue: allowed
    connection.close()
    assert bus.api.get_user(RECORDER_USER)["tags"] in ("", []), "no management access either"


def test_messages_carry_the_mission_their_robot_is_recorded_under(bus: Bus) -> None:
    on_mission, idle = bus.add("rec-on-mission"), bus.add("rec-idle")

    async def missions(robots: set[str]) -> dict[str, str]:
        return {robot: "survey-7" for robot in robots if robot == "rec-on-mission"}

    with bus.recorder(missions=missions) as recorder:
        for account in (on_mission, idle):
            bus.publish_raw(account, f"{account.name}.tf", b'{"a": 1}', message_id=f"{account.name}-1")
        wait_for(lambda: recorder.stats().recorded == 2, what="both recorded")
    assert [r.robot_id for r in bus.recorded("tf", mission_id="survey-7")] == ["rec-on-mission"]
    assert {r.robot_id: r.mission_id for r in bus.recorded("tf")} == {
        "rec-on-mission": "survey-7",
        "rec-idle": None,
    }


def test_beacons_are_recorded_and_those_the_broker_discarded_say_so(bus: Bus) -> None:
    guide = bus.add("rec-guide", kind=RobotKind.GUIDE)
    sighting = {"beacon_id": "b1", "rssi": -60}
    with bus.recorder() as recorder, bus.robot(guide) as robot:
        robot.publish(EventType.BEACON, sighting)  # the client sets the beacon headers
        connection = blocking_connection(guide.amqp_url)
        channel = connection.channel()
        channel.confirm_delivery()
        properties = pika.BasicProperties(user_id="rec-guide", message_id="no-headers", delivery_mode=2)
        channel.basic_publish(
            "rec-guide.beacon", "rec-guide.beacon", json.dumps(sighting).encode(), properties
        )
        connection.close()
        wait_for(lambda: recorder.stats().recorded == 2, what="both beacons recorded")
    passed, discarded = sorted(bus.recorded("beacon"), key=lambda r: r.message_id == "no-headers")
    assert (passed.exchange, passed.robot_id, passed.problem) == ("rec-guide.beacon", "rec-guide", None)
    assert (discarded.exchange, discarded.robot_id) == ("rec-guide.beacon", "rec-guide")
    assert discarded.problem == "discarded by the broker: no 'type' header; no 'codename' header"


def _children(pid: int) -> list[int]:
    """The live processes whose parent is ``pid`` (from each one's /proc stat: a thread's
    ``children`` file can vanish while it is read)."""
    children = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            continue  # exited meanwhile
        state, parent = fields[0], int(fields[1])
        if parent == pid and state != "Z":
            children.append(int(entry.name))
    return sorted(children)


def test_fleetbus_worker_records_in_a_child_that_is_restarted_and_dies_with_it(bus: Bus) -> None:
    explorer = bus.robot(bus.add("rec-explorer", kind=RobotKind.EXPLORER))
    worker_password = urlsplit(bus.service_accounts().service_url).password
    # the worker started with its password in FLEETBUS_SERVICE_URL, as an operator may start it
    worker = bus.spawn_worker(env={"FLEETBUS_SERVICE_URL": bus.service_accounts().service_url})
    try:
        wait_for(lambda: len(_children(worker.pid)) == 1, timeout=30, what="the recorder's process")
        [first] = _children(worker.pid)
        # it logs in as fleetbus-recorder: no broker password of the worker's is in its environment
        environment = Path(f"/proc/{first}/environ").read_bytes().decode()
        assert worker_password and worker_password not in environment
        explorer.publish(EventType.STATUS, status(70))
        wait_for(lambda: len(bus.recorded("status")) == 1, timeout=60, what="the status recorded")

        os.kill(first, signal.SIGKILL)
        wait_for(lambda: _children(worker.pid) not in ([], [first]), timeout=30, what="a new recorder")
        [second] = _children(worker.pid)
        explorer.publish(EventType.STATUS, status(60))
        wait_for(lambda: len(bus.recorded("status")) == 2, timeout=60, what="recording again")
        wait_for(
            lambda: bus.count(EventType.STATUS.value) == 2, timeout=60, what="the workers going on meanwhile"
        )

        worker.kill()  # SIGKILL: the worker cannot stop its child itself
        worker.wait(30)
        wait_for(lambda: not pid_alive(second), timeout=30, what="the recorder ending with its worker")
    finally:
        if worker.poll() is None:
            worker.kill()


def test_a_recorder_child_whose_worker_is_already_gone_ends_at_once() -> None:
    """The child asks for its death signal itself (no ``preexec_fn`` in the threaded worker), and
    checks its parent is still the worker that started it: one that died first leaves no orphan."""
    started = subprocess.run(
        [
            sys.executable,
            "-c",
            "from workers.recorder.process import die_with_parent as d; d(); print('alive')",
        ],
        env={**os.environ, PARENT_ENV: "1"},  # a parent that is not the one it has
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert started.returncode == 1 and "alive" not in started.stdout
    assert "the worker 1 that started this recorder is gone" in started.stderr


def test_no_process_of_the_project_forks_with_preexec_fn() -> None:
    """``preexec_fn`` runs Python between fork and exec, unsafe in a process with threads."""
    packages = ("api", "bench", "broker", "fleetbus", "publishers", "schemas", "workers")
    found = [
        str(path.relative_to(PROJECT_ROOT))
        for package in packages
        for path in (PROJECT_ROOT / package).rglob("*.py")
        if "preexec_fn=" in path.read_text()
    ]
    assert found == []


def test_the_recorders_environment_holds_no_broker_password_but_the_development_brokers() -> None:
    """With a URL naming the broker, the child needs no password of the worker's; with none, it
    finds the development broker as the worker did, by its password (else it would make another)."""
    named = {"FLEETBUS_SERVICE_URL": "amqp://fleetbus:secret@h/", "FLEETBUS_BROKER_PASSWORD": "dev"}
    env = recorder_environment(named, 7)
    assert env["FLEETBUS_SERVICE_URL"] == "amqp://fleetbus@h/" and "FLEETBUS_BROKER_PASSWORD" not in env
    unnamed = recorder_environment({"FLEETBUS_BROKER_PASSWORD": "dev", "FLEETBUS_API_SECRET": "s"}, 7)
    assert unnamed == {"FLEETBUS_BROKER_PASSWORD": "dev", "FLEETBUS_DIE_WITH_PARENT": "7"}
