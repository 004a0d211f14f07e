"""A local RabbitMQ cluster for development and tests: several :class:`LocalNode` joined as one.

Everything lives under one folder (``$FLEETBUS_DATA_DIR/cluster`` for ``fleetbus broker up
--nodes 3``): ``node1/``, ``node2/``... each a private node with its own name (derived from its
folder), ports, database and logs; ``tls/`` their shared certificates; ``cluster.json`` what was
decided once. Before the first start the cluster writes each node's ``node.json`` (its ports,
with ONE epmd port for all: Erlang nodes find each other through the epmd they share), ONE
Erlang cookie, and ONE ``admin.json`` (the administrator is cluster-wide once the nodes join).
Each node also gets ``conf.d/10-cluster.conf``: a modest memory bound, ``pause_minority`` and a
short ``net_ticktime`` so that a silent node is noticed in seconds.

The first start boots every node, then joins the second and later ones to the first with
``rabbitmqctl stop_app``, ``reset``, ``join_cluster``, ``start_app``. Later starts boot all nodes
at once (a clustered node waits at boot for the peers it last saw).
"""

from __future__ import annotations

import json
import logging
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

from fleetbus.broker.certificates import TlsFiles
from fleetbus.broker.probe import write_private_file
from fleetbus.private_files import private_dir
from fleetbus.publishers.addresses import join_addresses
from fleetbus_dev.local_node import (
    ADMIN_USER,
    HOST,
    PORT_NAMES,
    LocalNode,
    LocalNodeError,
    NodeInfo,
    choose_free_ports,
    ensure_certificates,
)

#: Each node's share of this machine: the broker blocks publishers beyond it (three nodes and the
#: tests fit a 2-core machine with some GB to spare).
NODE_MEMORY = "512MiB"
#: Seconds of silence before a node counts a peer as gone (RabbitMQ's default is 60).
NET_TICKTIME = 10

CLUSTER_CONF = f"""\
# Written by fleetbus (dev/fleetbus_dev/cluster.py); read after rabbitmq.conf.
vm_memory_high_watermark.absolute = {NODE_MEMORY}
cluster_partition_handling = pause_minority
net_ticktime = {NET_TICKTIME}
"""

log = logging.getLogger("fleetbus.broker")


@dataclass(frozen=True)
class ClusterInfo:
    nodes: list[NodeInfo]
    amqp_url: str | None
    """The administrator's URL with every node's address: ``amqp://fleetbus-admin:pw@127.0.0.1:p1,127.0.0.1:p2,.../``."""
    management_url: str | None
    """The first node's management API (every node answers for the whole cluster)."""

    @property
    def running(self) -> int:
        return sum(node.running for node in self.nodes)


class LocalCluster:
    """``size`` private nodes under ``base_dir`` joined into one cluster; see the module docstring."""

    def __init__(self, base_dir: Path | str, size: int = 3, tls: TlsFiles | None = None) -> None:
        self.base_dir = Path(base_dir).expanduser().resolve()
        self.tls = tls or TlsFiles.in_folder(self.base_dir / "tls")
        saved = self._saved()
        self.size = int(saved.get("size", size)) if saved else size
        if self.size < 1:
            raise LocalNodeError(f"a cluster needs at least one node, not {self.size}")
        self.nodes = [LocalNode(self.base_dir / f"node{i + 1}", self.tls) for i in range(self.size)]

    @property
    def state_file(self) -> Path:
        return self.base_dir / "cluster.json"

    def __repr__(self) -> str:
        return f"LocalCluster({str(self.base_dir)!r}, size={self.size})"

    def exists(self) -> bool:
        return self.state_file.exists()

    def _saved(self) -> dict[str, object]:
        if not self.state_file.exists():
            return {}
        data: dict[str, object] = json.loads(self.state_file.read_text())
        return data

    def _save(self, data: dict[str, object]) -> None:
        private_dir(self.base_dir)
        write_private_file(self.state_file, json.dumps(data, indent=2) + "\n")

    # ------------------------------------------------------------------ preparation (once)
    def _prepare(self) -> None:
        """Ports (one epmd for all), cookie and administrator, written for every node once."""
        if self.exists():
            return
        per_node = [name for name in PORT_NAMES if name != "epmd"]
        ports = choose_free_ports(len(per_node) * self.size + 1)
        epmd = ports.pop()
        cookie = secrets.token_hex(20).upper()
        admin = json.dumps({"username": ADMIN_USER, "password": secrets.token_urlsafe(24)}) + "\n"
        for index, node in enumerate(self.nodes):
            private_dir(node.base_dir)
            mine = dict(
                zip(per_node, ports[index * len(per_node) : (index + 1) * len(per_node)], strict=True)
            )
            mine["epmd"] = epmd
            ordered = {name: mine[name] for name in PORT_NAMES}
            write_private_file(
                node.node_file, json.dumps({"node_name": node.node_name, "ports": ordered}, indent=2) + "\n"
            )
            write_private_file(node.base_dir / ".erlang.cookie", cookie, mode=0o400)
            write_private_file(node.admin_file, admin)
        self._save(
            {"size": self.size, "epmd": epmd, "nodes": [n.node_name for n in self.nodes], "joined": []}
        )

    def _write_cluster_conf(self) -> None:
        for node in self.nodes:
            folder = node.base_dir / "conf.d"
            private_dir(folder)
            path = folder / "10-cluster.conf"
            if not path.exists() or path.read_text() != CLUSTER_CONF:
                write_private_file(path, CLUSTER_CONF)

    # ------------------------------------------------------------------ up / down
    def up(self, timeout: float = 180.0) -> ClusterInfo:
        """Start every node that is down (all at once) and join the ones not yet joined; return
        once each node's administrator can log in and the cluster lists every node as running."""
        deadline = time.monotonic() + timeout
        self._prepare()
        self._write_cluster_conf()
        ensure_certificates(self.tls)
        self._run_all([i for i, node in enumerate(self.nodes) if node.pid() is None], deadline)
        saved = self._saved()
        joined = list(saved.get("joined", []))  # type: ignore[call-overload]
        seed = self.nodes[0]
        for node in self.nodes[1:]:
            if node.node_name in joined:
                continue
            log.info("joining %s to %s", node.node_name, seed.node_name)
            node.rabbitmqctl("stop_app")
            node.rabbitmqctl("reset")
            node.rabbitmqctl("join_cluster", seed.node_name)
            node.rabbitmqctl("start_app")
            node.rabbitmqctl("await_startup", timeout=max(5.0, deadline - time.monotonic()))
            joined.append(node.node_name)
            self._save({**saved, "joined": joined})
        self.wait_members(deadline)
        return self.status()

    def start_node(self, index: int, timeout: float = 120.0) -> NodeInfo:
        """Start one node again (after :meth:`kill` or :meth:`stop_node`)."""
        return self.nodes[index].up(timeout=timeout)

    def stop_node(self, index: int, timeout: float = 60.0) -> None:
        """A clean shutdown of one node; the cluster's epmd stays for the others."""
        self.nodes[index].down(timeout=timeout, stop_epmd=False)

    def kill(self, index: int) -> None:
        """SIGKILL one node's VM and wait until it is gone."""
        self.nodes[index].kill()

    def partition(self, index: int) -> None:
        """Cut one node off from the others, as a network partition of the distribution does: it
        uses a wrong cookie towards each peer and drops its links, so neither side can reconnect
        (``rabbitmqctl`` still reaches it: the CLI uses the default cookie). With
        ``pause_minority`` the node then pauses itself; the majority carries on."""
        peers = self._peer_atoms(index)
        self.nodes[index].rabbitmqctl(
            "eval",
            f"[begin erlang:set_cookie(N, fleetbus_partitioned), erlang:disconnect_node(N) end "
            f"|| N <- [{peers}]], ok.",
        )

    def heal(self, index: int) -> None:
        """Undo :meth:`partition`: the right cookie again, and a ping to each peer."""
        peers = self._peer_atoms(index)
        self.nodes[index].rabbitmqctl(
            "eval",
            f"C = erlang:get_cookie(), [erlang:set_cookie(N, C) || N <- [{peers}]], "
            f"[net_adm:ping(N) || N <- [{peers}]], ok.",
        )

    def _peer_atoms(self, index: int) -> str:
        return ", ".join(f"'{node.node_name}'" for i, node in enumerate(self.nodes) if i != index)

    def down(self, timeout: float = 90.0) -> None:
        """Stop every node (the last one first), then the shared epmd."""
        deadline = time.monotonic() + timeout
        for node in reversed(self.nodes):
            node.down(timeout=max(10.0, deadline - time.monotonic()), stop_epmd=False)
        self.nodes[0].down(timeout=max(10.0, deadline - time.monotonic()), stop_epmd=True)

    def _run_all(self, indexes: list[int], deadline: float) -> None:
        errors: list[BaseException] = []

        def start(node: LocalNode) -> None:
            try:
                node.up(timeout=max(10.0, deadline - time.monotonic()))
            except BaseException as error:  # reported below, after every start ended
                errors.append(error)

        threads = [threading.Thread(target=start, args=(self.nodes[i],)) for i in indexes]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        if errors:
            raise errors[0]

    # ------------------------------------------------------------------ state
    def members(self) -> tuple[set[str], set[str]]:
        """(every member, the running ones) as the first running node reports them."""
        for node in self.nodes:
            if node.pid() is None:
                continue
            try:
                result = node.rabbitmqctl("cluster_status", "--formatter", "json", check=False, timeout=30)
            except LocalNodeError as error:  # the CLI timed out (a node starting, a loaded machine)
                log.info("cluster_status on %s: %s", node.node_name, error)
                continue
            if result.returncode == 0:
                data = json.loads(result.stdout)
                return set(data.get("disk_nodes", [])) | set(data.get("ram_nodes", [])), set(
                    data.get("running_nodes", [])
                )
        return set(), set()

    def wait_members(self, deadline: float) -> None:
        names = {node.node_name for node in self.nodes}
        while True:
            _, running = self.members()
            if names <= running:
                return
            if time.monotonic() >= deadline:
                raise LocalNodeError(f"the cluster runs {sorted(running)}, not all of {sorted(names)}")
            time.sleep(0.5)

    def amqp_url(self, vhost: str = "") -> str | None:
        creds = self.nodes[0].admin_credentials()
        ports = [node.ports() for node in self.nodes]
        if creds is None or any(p is None for p in ports):
            return None
        user, password = (quote(part, safe="") for part in creds)
        return join_addresses(
            [f"amqp://{user}:{password}@{HOST}:{p['amqp']}/{vhost}" for p in ports if p is not None]
        )

    def management_url(self, index: int | None = None) -> str | None:
        """Node ``index``'s management API; by default every node's, as one URL the management
        client fails over along (each node answers for the whole cluster)."""
        indexes = range(len(self.nodes)) if index is None else [index]
        ports = [self.nodes[i].ports() for i in indexes]
        if any(p is None for p in ports):
            return None
        return join_addresses([f"http://{HOST}:{p['management']}/" for p in ports if p is not None])

    def status(self) -> ClusterInfo:
        return ClusterInfo([node.status() for node in self.nodes], self.amqp_url(), self.management_url())
