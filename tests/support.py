"""Test helpers that run fleetbus against the real broker: a fresh virtual host per test."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import pika

from broker.accounts import Account, Role, fresh_vhost, provision_account
from broker.endpoint import BrokerEndpoint
from broker.management import ManagementAPI
from fleetbus.config import Settings, load_settings
from fleetbus.registry import register_robot
from publishers.client import RobotClient
from schemas.routing import RobotKind
from workers.recorder.consumer import MissionLookup
from workers.recorder.runner import recorder_options
from workers.recorder.thread import RecorderThread
from workers.store import Store, open_recording_store, run_with_store
from workers.store.base import EventQuery, EventRecord
from workers.store.recordings import RecordedMessage, RecordQuery
from workers.thread import WorkerThread

T = TypeVar("T")
PROJECT_ROOT = Path(__file__).resolve().parent.parent


def wait_for(
    condition: Callable[[], T], timeout: float = 30.0, what: str = "condition", interval: float = 0.05
) -> T:
    """Poll ``condition`` until it returns something truthy; fail with ``what`` at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(
                f"timed out after {timeout:.0f} s waiting for {what} (last value: {value!r})"
            )
        time.sleep(interval)


@dataclass
class Bus:
    """One test's slice of the real broker: its own virtual host, data directory and accounts."""

    endpoint: BrokerEndpoint
    api: ManagementAPI
    vhost: str
    settings: Settings

    @property
    def admin_url(self) -> str:
        assert self.settings.amqp_url is not None
        return self.settings.amqp_url

    accounts: list[str] = field(default_factory=list)

    def add(self, name: str, role: Role = Role.ROBOT, kind: RobotKind | None = None) -> Account:
        """A new account; users are broker-wide, so one left by an aborted run is re-keyed."""
        self.accounts.append(name)
        account = asyncio.run(provision_account(self.admin_url, self.api, name, role, kind, rotate=True))
        if role is Role.ROBOT:
            register_robot(self.settings, name, kind)
        return account

    def remove_accounts(self) -> None:
        for name in self.accounts:
            self.api.delete_user(name)

    def robot(self, account: Account, **kwargs: Any) -> RobotClient:
        client = RobotClient(account.amqp_url, state_dir=self.settings.robots_dir, **kwargs)
        client.connect()
        return client

    @contextmanager
    def worker(self) -> Iterator[WorkerThread]:
        thread = WorkerThread(self.settings, replace(self.endpoint, amqp_url=self.admin_url)).start()
        try:
            yield thread
        finally:
            thread.stop()

    @contextmanager
    def recorder(self, missions: MissionLookup | None = None, **options: Any) -> Iterator[RecorderThread]:
        """The recorder, with these :class:`RecorderOptions` over the settings' ones."""
        endpoint = replace(self.endpoint, amqp_url=self.admin_url)
        options_ = recorder_options(self.settings, **options)
        thread = RecorderThread(self.settings, endpoint, options_, missions).start()
        try:
            yield thread
        finally:
            thread.stop()

    def recorded(self, type: str, **query: Any) -> list[RecordedMessage]:
        """Records of ``type`` in the test's recording (a :class:`RecordQuery`'s fields)."""

        async def go() -> list[RecordedMessage]:
            async with open_recording_store(self.settings) as store:
                return await store.find_recorded(RecordQuery(type, **query))

        return asyncio.run(go())

    def publish_raw(self, account: Account, routing_key: str, body: bytes, **properties: Any) -> None:
        """Publish as the account with pika, confirmed: what any AMQP client of a robot could send."""
        connection = pika.BlockingConnection(pika.URLParameters(account.amqp_url))
        try:
            channel = connection.channel()
            channel.confirm_delivery()
            props = pika.BasicProperties(user_id=account.name, delivery_mode=2, **properties)
            channel.basic_publish(f"{account.name}.events", routing_key, body, props, mandatory=True)
        finally:
            connection.close()

    def worker_env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.update(
            FLEETBUS_AMQP_URL=self.admin_url,
            FLEETBUS_MANAGEMENT_URL=self.endpoint.management_url,
            FLEETBUS_DATA_DIR=str(self.settings.data_dir),
        )
        env.pop("FLEETBUS_MONGODB_URL", None) if self.settings.mongodb_url is None else None
        return env

    def spawn_worker(self) -> subprocess.Popen[bytes]:
        """The worker as its own process (``python -m fleetbus worker``), to be killed for real."""
        log = open(self.settings.data_dir / f"worker-{uuid.uuid4().hex[:6]}.log", "wb")
        return subprocess.Popen(
            [sys.executable, "-m", "fleetbus", "worker"],
            env=self.worker_env(),
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    def with_store(self, operation: Callable[[Store], Awaitable[T]]) -> T:
        """Run one operation on a fresh connection to the test's store (what an operator would see)."""
        return run_with_store(self.settings, operation)

    def find(self, query: EventQuery | None = None) -> list[EventRecord]:
        return self.with_store(lambda store: store.find_events(query or EventQuery()))

    def count(self, type: str | None = None, robot_id: str | None = None) -> int:
        return self.with_store(lambda store: store.count_events(type, robot_id))

    def ready_messages(self, queue: str) -> int:
        """Messages ready in ``queue`` now (AMQP passive declare; the HTTP API lags seconds)."""
        connection = pika.BlockingConnection(pika.URLParameters(self.admin_url))
        try:
            return connection.channel().queue_declare(queue, passive=True).method.message_count
        finally:
            connection.close()


@contextmanager
def fresh_bus(endpoint: BrokerEndpoint, api: ManagementAPI, data_dir: Path) -> Iterator[Bus]:
    """A new virtual host and data directory on ``endpoint``; accounts and vhost removed after."""
    vhost = f"test-{uuid.uuid4().hex[:10]}"
    admin_url = fresh_vhost(api, endpoint.amqp_url, vhost)
    settings = replace(
        load_settings(),
        data_dir=data_dir,
        amqp_url=admin_url,
        management_url=endpoint.management_url,
        mongodb_url=None,
    )
    bus = Bus(endpoint, api, vhost, settings)
    try:
        yield bus
    finally:
        bus.remove_accounts()
        api.delete_vhost(vhost)
