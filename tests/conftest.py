"""Fixtures: the broker the README's command starts, a fresh virtual host per test, and MongoDB.

MongoDB runs use ``FLEETBUS_MONGODB_URL`` when set, else mongoeco's MongoDB wire-protocol
server started here under Python 3.13 (the venv ``.venv-mongoeco`` that scripts/setup makes),
one per pytest-xdist worker.

In parallel (``pytest -n N``, as ``scripts/test`` runs it), each xdist worker has a broker node
of its own: broker users are node-wide, and every test names its robots alike (``explorer1``)
and re-keys the service accounts (``fleetbus``) in its fresh data directory, so two tests at once
on one node would replace each other's passwords and delete each other's users. The first worker
(or a run in one process) uses the node ``fleetbus broker up`` started; the others each start a
private node in their temporary folder and stop it at the end. The tests that kill a broker
(``killable_node``) kill that private node of their worker, which runs one test at a time; the
first worker, or a run in one process, starts a node of their own for them instead of killing
the one ``fleetbus broker up`` started.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from fleetbus.broker.certificates import make_certificates
from fleetbus.broker.endpoint import BrokerEndpoint
from fleetbus.broker.management import ManagementAPI
from fleetbus.settings import load_settings
from fleetbus_dev.fallback import resolve_broker
from fleetbus_dev.local_node import LocalNode
from tests import reaper
from tests.link import NetworkLink
from tests.run_tls import run_tls_files, suite_endpoint
from tests.store.conftest import fresh_database
from tests.store.mongodb import mongodb_url  # noqa: F401  (the MongoDB fixture, shared)
from tests.support import Bus, fresh_bus

#: Password hashes of 1 MiB instead of 64 in every process of the suite (the API in-process and as
#: `fleetbus api`): the same argon2id at a hundredth of the CPU, for the hundreds of hashes the
#: tests make. What they check does not depend on the cost; the test of a login that keeps argon2
#: busy makes its own costly hash.
os.environ.setdefault("FLEETBUS_API_HASH_MEMORY_KIB", "1024")

#: Modules of tests that take tens of seconds each (worker processes killed and restarted, outages,
#: every bench scenario): they start first, so that no xdist worker begins one when the rest is done.
LONG_MODULES = frozenset(
    {
        "test_cluster_failover.py",
        "test_cluster_workers.py",
        "test_scaling.py",
        "test_bench.py",
        "test_outages.py",
        "test_shards.py",
        "test_robot_runs.py",
        "test_openapi_schemathesis.py",
    }
)

#: The two-node tests of sites (``tests/sites/``): one xdist worker runs them all, so that one pair
#: of nodes is booted for the run rather than one per worker.
SITES_TESTS = "tests/sites/"

#: Modules whose tests share a module-scoped node or app, and need their order (the local node's
#: last test stops it): one xdist worker runs each of them whole.
ONE_WORKER_MODULES = frozenset(
    {"tests/test_local_node.py", "tests/test_packaging.py", "tests/api/test_roles.py"}
)

#: The tests on a three-node cluster: one xdist worker runs them all, on one cluster.
CLUSTER_TESTS = "tests/cluster/"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest tests first (the ``slow`` outages, then ``LONG_MODULES``), each module's in its
    order."""
    items.sort(
        key=lambda item: (
            item.get_closest_marker("slow") is None,
            item.path.name not in LONG_MODULES and not item.nodeid.startswith(SITES_TESTS),
        )
    )


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """Test by test to whichever worker is free, but each of ``ONE_WORKER_MODULES`` whole to one, and
    every test of ``SITES_TESTS`` to one.

    (xdist's own ``xdist_group`` mark does not work with pytest 9.2: xdist 3.8 tags the group onto
    ``item._nodeid``, which pytest no longer reads.)"""
    from xdist.scheduler import LoadScopeScheduling

    class ModulesWhole(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            if module.startswith(CLUSTER_TESTS):
                return CLUSTER_TESTS  # one worker boots the three-node cluster for them all
            if module.startswith(SITES_TESTS):
                return SITES_TESTS
            return module if module in ONE_WORKER_MODULES else nodeid

    return ModulesWhole(config, log)


def pytest_configure(config: pytest.Config) -> None:
    """The run's certificates, made once by the controlling process before any xdist worker starts
    a node with them (two workers making them at once would each make a CA of their own)."""
    if not hasattr(config, "workerinput"):
        files = run_tls_files()
        if not files.server_ready():
            make_certificates(files)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Nodes of a run that is killed are stopped anyway (``tests/reaper.py``): the controlling
    process has a watcher for the run's temporary folder, where every test node lives."""
    if not hasattr(session.config, "workerinput"):
        reaper.start(os.getpid(), session.config._tmp_path_factory.getbasetemp())  # type: ignore[attr-defined]


def has_own_node() -> bool:
    """Whether this process's tests run on a node it started (an xdist worker but the first)."""
    return os.environ.get("PYTEST_XDIST_WORKER", "gw0") != "gw0"


@pytest.fixture(scope="session")
def broker_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalNode | None]:
    """The private node this process's tests use (see the module docstring); None when the broker
    is a configured one (``FLEETBUS_AMQP_URL``) or Docker's."""
    settings = load_settings()
    shared = resolve_broker(settings, start=True)  # the same code path as `fleetbus broker up`
    if not has_own_node():
        yield LocalNode(settings.broker_dir, run_tls_files()) if shared.kind == "private" else None
        return
    if shared.kind != "private":
        pytest.exit(
            f"the {shared.kind} broker is one node for every xdist worker, and broker users are "
            "node-wide: run the suite in one process (-n 0)",
            returncode=4,
        )
    node = LocalNode(tmp_path_factory.mktemp("broker") / "broker", run_tls_files())
    node.up()
    try:
        yield node
    finally:
        node.kill()  # a throwaway node: no need for a clean shutdown's seconds
        node.down()  # its epmd


@pytest.fixture(scope="session")
def endpoint(broker_node: LocalNode | None) -> BrokerEndpoint:
    """The broker as administrator: the private node of this process, or the configured one."""
    if broker_node is None:
        return resolve_broker(load_settings(), start=True)
    return suite_endpoint(broker_node.status())


@pytest.fixture(scope="session")
def management(endpoint: BrokerEndpoint) -> Iterator[ManagementAPI]:
    with ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api:
        yield api


@pytest.fixture
def bus(endpoint: BrokerEndpoint, management: ManagementAPI, tmp_path: Path) -> Iterator[Bus]:
    with fresh_bus(endpoint, management, tmp_path) as test_bus:
        yield test_bus


async def with_each_store(request: pytest.FixtureRequest, bus: Bus) -> AsyncIterator[Bus]:
    """``bus`` with the store ``request.param`` names: the embedded SQLite, or a MongoDB database
    of its own."""
    if request.param == "mongodb":
        url: str = request.getfixturevalue("mongodb_url")
        async with fresh_database(url) as database:
            bus.settings = bus.settings.updated(mongodb_url=url.rstrip("/") + "/" + database)
            yield bus
        return
    yield bus


@pytest.fixture(params=["sqlite", "mongodb"])
async def stored_bus(request: pytest.FixtureRequest, bus: Bus) -> AsyncIterator[Bus]:
    """The test's bus with each store: the embedded SQLite, or a MongoDB database of its own."""
    async for each in with_each_store(request, bus):
        yield each


@pytest.fixture(scope="session")
def killable_node(
    broker_node: LocalNode | None, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[LocalNode]:
    """A private node the tests may kill: this worker's own (see the module docstring), else one
    started for them (never the node `fleetbus broker up` started, nor a configured broker)."""
    if has_own_node() and broker_node is not None:
        yield broker_node
        return
    node = LocalNode(tmp_path_factory.mktemp("killable") / "broker", run_tls_files())
    node.up()
    try:
        yield node
    finally:
        node.kill()  # a throwaway node: no need for a clean shutdown's seconds
        node.down()  # its epmd


@pytest.fixture
def killable_bus(killable_node: LocalNode, tmp_path: Path) -> Iterator[Bus]:
    """A fresh virtual host on the killable node, started again if an earlier test left it down."""
    endpoint = suite_endpoint(killable_node.up())
    with (
        ManagementAPI.from_urls(endpoint.management_url, endpoint.amqp_url) as api,
        fresh_bus(endpoint, api, tmp_path) as test_bus,
    ):
        try:
            yield test_bus
        finally:
            killable_node.up()  # a test that failed while the node was down: its vhost is removed


@pytest.fixture(params=["sqlite", "mongodb"])
async def stored_killable_bus(request: pytest.FixtureRequest, killable_bus: Bus) -> AsyncIterator[Bus]:
    """The killable node's bus with each store."""
    async for each in with_each_store(request, killable_bus):
        yield each


@pytest.fixture
def link_for(bus: Bus) -> Iterator[list[NetworkLink]]:
    """The network links a test makes (``tests.support.network_link``), stopped after it."""
    links: list[NetworkLink] = []
    yield links
    for link in links:
        link.stop()
