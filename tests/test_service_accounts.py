"""Least privilege per process: `fleetbus setup` is the administrator's step, run once; the worker
and its recorder then run with the `fleetbus` and `fleetbus-recorder` accounts alone."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from urllib.parse import urlsplit

from fleetbus.broker.accounts import RECORDER_USER, SERVICE_USER, kept_password_file
from fleetbus.schemas.routing import EXPRESS_QUEUE, INGEST_QUEUE, RECORDER_QUEUE, RobotKind
from fleetbus.workers.setup import set_up_service
from tests.factories import hazard
from tests.support import Bus, wait_for


def test_the_worker_runs_with_the_service_account_alone(bus: Bus) -> None:
    accounts = bus.service_accounts()  # `fleetbus setup`, as the administrator
    admin_password = urlsplit(bus.admin_url).password
    assert admin_password
    for account in (SERVICE_USER, RECORDER_USER):
        assert kept_password_file(bus.settings.accounts_dir, account).stat().st_mode & 0o077 == 0
    explorer = bus.add("sa-explorer", kind=RobotKind.EXPLORER)

    env = bus.service_env()
    assert "FLEETBUS_AMQP_URL" not in env and "FLEETBUS_MANAGEMENT_URL" not in env
    assert not [name for name, value in env.items() if admin_password in value]
    assert urlsplit(env["FLEETBUS_SERVICE_URL"]).password is None, "the password comes from the kept file"
    worker = bus.spawn_worker()  # with its recorder child
    try:

        def consumers() -> dict[str, str]:
            return {
                consumer["queue"]["name"]: consumer["channel_details"]["user"]
                for consumer in bus.api.list_consumers(bus.vhost)
                if (consumer.get("channel_details") or {}).get("user")
            }

        expected = {
            INGEST_QUEUE: SERVICE_USER,
            EXPRESS_QUEUE: SERVICE_USER,
            "fleetbus.rpc.requests": SERVICE_USER,
            "fleetbus.beacon.discarded": SERVICE_USER,
            "fleetbus.overflow.dropped": SERVICE_USER,
            "fleetbus.site-hazards": SERVICE_USER,  # the sites' hazard states (none here)
            RECORDER_QUEUE: RECORDER_USER,
        }
        # the worker consumes its other queues after the ingest shards and the express lane
        wait_for(
            lambda: worker.poll() is not None or consumers() == expected,
            60,
            "the worker and its recorder consuming each of their queues with their own accounts",
        )
        assert worker.poll() is None, "the worker ended"
        assert consumers() == expected
        robot = bus.robot(explorer)
        robot.publish("hazard", hazard())
        wait_for(lambda: bus.count("hazard") == 1, what="the hazard to be stored")
        wait_for(lambda: len(bus.recorded("hazard")) == 1, what="the hazard to be recorded")

        users = {c["user"] for c in bus.api.list_connections() if c.get("vhost") == bus.vhost}
        assert {SERVICE_USER, RECORDER_USER} <= users <= {SERVICE_USER, RECORDER_USER, "sa-explorer"}, users
        assert accounts.service_url.startswith((f"amqp://{SERVICE_USER}:", f"amqps://{SERVICE_USER}:"))
    finally:
        worker.send_signal(signal.SIGTERM)
        assert worker.wait(60) == 0


def test_the_recording_process_is_the_commands_own_and_shows_no_password(bus: Bus) -> None:
    """`fleetbus recorder run` execs the recording process without the command line: the same
    process records (a SIGTERM from whoever started it reaches it), and the account's password
    is in neither its arguments nor its environment."""
    password = urlsplit(bus.service_accounts().recorder_url).password
    assert password
    explorer = bus.add("sa-recorded", kind=RobotKind.EXPLORER)
    with open(bus.settings.data_dir / "recorder.log", "wb") as log:
        recorder = subprocess.Popen(
            [sys.executable, "-m", "fleetbus", "recorder", "run"],
            env=bus.service_env(),
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        wait_for(
            lambda: (
                recorder.poll() is not None
                or any(c["queue"]["name"] == RECORDER_QUEUE for c in bus.api.list_consumers(bus.vhost))
            ),
            60,
            "the recorder to consume",
        )
        assert recorder.poll() is None, "the recorder ended"
        arguments = Path(f"/proc/{recorder.pid}/cmdline").read_bytes().split(b"\0")
        assert arguments[1:3] == [b"-m", b"fleetbus.workers.recorder"], arguments
        environment = Path(f"/proc/{recorder.pid}/environ").read_bytes()
        assert password.encode() not in b" ".join(arguments) + environment
        bus.robot(explorer).publish("hazard", hazard())
        wait_for(lambda: len(bus.recorded("hazard")) == 1, what="the hazard to be recorded")
    finally:
        recorder.send_signal(signal.SIGTERM)
        assert recorder.wait(60) == 0


def test_setup_is_idempotent_and_keeps_the_recorder_least_privileged(bus: Bus) -> None:
    first = bus.service_accounts()
    again = asyncio.run(set_up_service(bus.settings, replace(bus.endpoint, amqp_url=bus.admin_url)))
    assert again == first, "the kept passwords stay valid: a second setup re-keys nothing"
    assert bus.api.get_permissions(bus.vhost, RECORDER_USER) == {
        "user": RECORDER_USER,
        "vhost": bus.vhost,
        "configure": "^$",
        "write": "^$",
        "read": f"^{RECORDER_QUEUE.replace('.', chr(92) + '.')}$",
    }
    tags = bus.api.get_user(RECORDER_USER)
    assert tags is not None and not tags.get("tags"), "no management UI for the recorder"
