"""A robot nobody on the project wrote: Node.js on amqplib (``tests/peers/robot.mjs``), its messages
built from the AsyncAPI document ``fleetbus schemas DIR`` writes, and nothing else.

Its accounts are made with ``fleetbus users add``, as a user would; it connects over AMQPS and
verifies the broker with the CA file it is given (``cacertfile`` in the URL is ignored by amqplib).
An explorer publishes a hazard and a status with publisher confirms; a warden, localised first as
the document's gate rule says, gets the hazard's announcement and calls ``hazard.open``; each
message the explorer breaks the contract with meets the outcome the document gives for it. Against
the real broker, worker and store.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from fleetbus.broker.certificates import TlsFiles, make_certificates
from fleetbus.schemas.export import write_json_schemas
from fleetbus.schemas.routing import RobotKind
from fleetbus.workers.store.base import EventQuery
from tests.peers import PEERS, node
from tests.run_tls import BROKER_TLS, run_tls_files
from tests.support import Bus, read_line, wait_for

TIMEOUT_S = 60
pytestmark = pytest.mark.skipif(
    not BROKER_TLS, reason="FLEETBUS_TEST_TLS=0: the run is over plain AMQP, the contract's server is AMQPS"
)


def fleetbus(bus: Bus, *args: str) -> subprocess.Popen[str]:
    """A `fleetbus` command on the test's broker slice, as the administrator, started."""
    env = {**os.environ, **bus.worker_env(), "COLUMNS": "400"}
    return subprocess.Popen(
        [sys.executable, "-m", "fleetbus", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def output(command: subprocess.Popen[str]) -> str:
    """What a `fleetbus` command printed, once it ended well."""
    out, err = command.communicate(timeout=120)
    assert command.returncode == 0, err
    return out


def add_user(bus: Bus, name: str, kind: RobotKind) -> subprocess.Popen[str]:
    """`fleetbus users add NAME --kind KIND`, started (its accounts removed after the test)."""
    bus.accounts.append(name)
    return fleetbus(bus, "users", "add", name, "--kind", kind.value)


def printed_url(command: subprocess.Popen[str]) -> str:
    """The URL `fleetbus users add` printed."""
    [url] = re.findall(r"^amqps?://\S+$", output(command), re.MULTILINE)
    return url


def start_robot(
    bus: Bus, role: str, url: str, contract: Path, ca: Path | None = None, **extra: Any
) -> subprocess.Popen[str]:
    """``node robot.mjs`` with its configuration (the URL and its password included) on stdin."""
    robot = subprocess.Popen(
        [node(), str(PEERS / "robot.mjs")],
        cwd=PEERS,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=open(bus.settings.data_dir / f"node-{role}.log", "wb"),
        text=True,
    )
    assert robot.stdin is not None
    settings = {"role": role, "url": url, "ca": str(ca or run_tls_files().ca), "asyncapi": str(contract)}
    robot.stdin.write(json.dumps({**settings, "timeout_s": TIMEOUT_S, **extra}))
    robot.stdin.close()
    return robot


def steps(bus: Bus, robot: subprocess.Popen[str], role: str) -> list[dict[str, Any]]:
    """What the robot printed, once it ended well."""
    assert robot.stdout is not None
    output = robot.stdout.read()
    code = robot.wait(TIMEOUT_S)
    log = (bus.settings.data_dir / f"node-{role}.log").read_text()
    assert code == 0, f"the Node.js {role} failed ({code}): {log}\n{output}"
    return [json.loads(line) for line in output.splitlines()]


def test_a_node_robot_built_from_the_asyncapi_document_alone(bus: Bus, tmp_path: Path) -> None:
    bus.service_accounts()  # `fleetbus setup`, and the store made, before the commands run side by side
    assert bus.count() == 0
    commands = [
        add_user(bus, "explorer1", RobotKind.EXPLORER),
        add_user(bus, "warden1", RobotKind.WARDEN),
        fleetbus(bus, "schemas", str(tmp_path / "contract")),
    ]
    explorer_url, warden_url = printed_url(commands[0]), printed_url(commands[1])
    output(commands[2])
    assert "cacertfile=" in explorer_url, "the URL names the CA the Python way; the Node robot ignores it"
    contract = tmp_path / "contract" / "asyncapi.json"

    with bus.worker():
        robots = [start_robot(bus, "warden", warden_url, contract)]
        try:
            read_line(robots[0], '{"step":"localised"', TIMEOUT_S)  # the gate rule: localised first
            robots.append(start_robot(bus, "explorer", explorer_url, contract, other="warden1"))
            done = steps(bus, robots[1], "explorer")
            heard = steps(bus, robots[0], "warden")
        finally:
            for process in robots:
                if process.poll() is None:
                    process.kill()
        malformed = {step["message_id"]: step for step in done if step["step"] == "malformed"}
        letters = wait_for(
            lambda: (found := bus.dead_letters()) and len(found) >= len(malformed) and found,
            what="every malformed message dead-lettered",
        )
        wait_for(lambda: bus.count() == 3, what="the hazard, the status and the localisation stored")

    [connected] = [step for step in done if step["step"] == "connected"]
    assert connected["protocol"] == "amqps" and connected["port"] == connected["document_port"], (
        "the document's server is the broker `fleetbus users add` hands out"
    )
    published = {step["type"]: step for step in done if step["step"] == "published"}
    stored = {(r.robot_id, r.type): r for r in bus.find(EventQuery())}
    assert set(stored) == {("explorer1", "hazard"), ("explorer1", "status"), ("warden1", "localisation")}
    for event_type, step in published.items():
        record = stored[("explorer1", event_type)]
        assert (record.epoch, record.seq) == (step["epoch"], step["seq"])
        assert record.message_id == step["message_id"]
        assert record.user_id == "explorer1" and record.exchange == "explorer1.events"
    assert stored[("explorer1", "hazard")].body["description"] == "Gas leak (reported by a Node.js robot)"

    # each broken message: dead-lettered with the reason the document gives, nothing of it stored
    assert {letter.message_id: letter.reason for letter in letters} == {
        message_id: step["expect"] for message_id, step in malformed.items()
    }
    cases = {"missing-field", "content-type", "oversize", "transient"}
    assert {step["case"] for step in malformed.values()} == cases
    by_case = {malformed[letter.message_id]["case"]: letter for letter in letters}
    assert f"body.{malformed[by_case['missing-field'].message_id]['field']}: Field required" in (
        by_case["missing-field"].detail
    )
    assert "content_type is 'text/plain'" in by_case["content-type"].detail
    assert "the limit is" in by_case["oversize"].detail
    [forged] = [step for step in done if step["step"] == "forged"]
    assert (forged["code"], forged["confirmed"]) == (406, False), forged
    assert "PRECONDITION_FAILED" in forged["message"] and "warden1" in forged["message"]

    # the warden, localised first, was told of the hazard, and the service answered its call
    [announced] = [step["notification"] for step in heard if step["step"] == "announced"]
    assert announced["hazard_state"] == "announced" and announced["hazard_id"] >= 1
    event = announced["event"]
    assert (event["robot_id"], event["seq"], event["message_id"]) == (
        "explorer1",
        published["hazard"]["seq"],
        published["hazard"]["message_id"],
    )
    [service] = [step for step in heard if step["step"] == "service"]
    assert service["reply"]["ok"] is True
    [hazard] = service["reply"]["result"]
    assert (hazard["hazard_id"], hazard["state"], hazard["robot_id"]) == (
        announced["hazard_id"],
        "announced",
        "explorer1",
    )


def test_the_node_robot_refuses_a_broker_its_ca_did_not_sign(bus: Bus, tmp_path: Path) -> None:
    """It verifies the broker with the CA file it is given, not with whatever the URL names."""
    account = bus.add("explorer1", kind=RobotKind.EXPLORER)
    [contract] = [path for path in write_json_schemas(tmp_path / "contract") if path.name == "asyncapi.json"]
    other = TlsFiles.in_folder(tmp_path / "another-ca")
    make_certificates(other)
    robot = start_robot(bus, "explorer", account.amqp_url, contract, ca=other.ca, other="warden1")
    assert robot.stdout is not None
    output, code = robot.stdout.read(), robot.wait(TIMEOUT_S)
    log = (bus.settings.data_dir / "node-explorer.log").read_text()
    assert code == 1 and "published" not in output, output
    assert "self-signed certificate in certificate chain" in log, log
