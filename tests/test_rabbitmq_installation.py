"""The RabbitMQ installation a private node runs from (``FLEETBUS_RABBITMQ_ROOT``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from fleetbus_dev.local_node import LocalNode, LocalNodeError
from fleetbus_dev.rabbitmq import HOST, Installation, mount_points, version_key


def test_a_root_gets_the_top_level_folders_of_the_nodes_files_but_never_over_its_own_system() -> None:
    folders = [
        Path("/tmp/pytest-of-root/pytest-3/broker0/broker"),
        Path("/tmp/pytest-of-root/pytest-3/tls"),
        Path("/work/fleetbus/.fleetbus/broker"),
        Path("/var/lib/fleetbus/broker"),
        Path("/var/lib/fleetbus/broker/mnesia"),
    ]
    assert mount_points(folders) == [Path("/tmp"), Path("/var/lib/fleetbus/broker"), Path("/work")]


def test_the_host_runs_the_tools_themselves_and_a_root_through_a_namespace_of_its_own(tmp_path: Path) -> None:
    host = Installation(HOST).command("rabbitmqctl", ["status"], [tmp_path], tmp_path)
    assert host == ["/usr/lib/rabbitmq/bin/rabbitmqctl", "status"]
    root = Installation(Path("/srv/debian13")).command("rabbitmqctl", ["status"], [tmp_path], tmp_path)
    assert root[:5] == ["unshare", "--mount", "--propagation", "private", "--"]
    script = root[-1]
    assert "mount --rbind /tmp /srv/debian13/tmp" in script
    assert script.rstrip().endswith(f"sh {tmp_path} /usr/lib/rabbitmq/bin/rabbitmqctl status")


@pytest.mark.rabbitmq_versions
def test_a_node_refuses_a_release_that_cannot_open_its_database_before_starting_anything(
    tmp_path: Path,
) -> None:
    node = LocalNode(tmp_path / "broker")
    rabbitmq = node.installation()
    version = rabbitmq.version()
    assert version is not None, rabbitmq.describe()
    # a database made by the other major release: 4.x cannot open a 3.x one, nor 3.x a 4.x one
    other = "3.10.8" if version_key(version) >= (4,) else "4.0.5"
    (node.base_dir / "mnesia" / node.node_name).mkdir(parents=True)
    node.made_with_file.write_text(json.dumps({"root": "/nowhere", "version": other}))
    with pytest.raises(LocalNodeError) as refused:
        node.up(timeout=30)
    message = str(refused.value)
    assert f"last run by RabbitMQ {other}" in message and "cannot open its database" in message
    assert f"delete {node.base_dir / 'mnesia'}" in message
    assert node.pid() is None and not node.node_file.exists(), "nothing was started"


@pytest.mark.rabbitmq_versions
def test_the_release_a_node_runs_is_the_one_that_made_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A node made by an older fleetbus (no record) is the host's; a recorded one keeps its own
    unless FLEETBUS_RABBITMQ_ROOT names another."""
    monkeypatch.delenv("FLEETBUS_RABBITMQ_ROOT", raising=False)
    legacy = LocalNode(tmp_path / "legacy" / "broker")
    (legacy.base_dir / "mnesia" / legacy.node_name).mkdir(parents=True)
    assert legacy.installation() == Installation(HOST)
    recorded = LocalNode(tmp_path / "recorded" / "broker")
    recorded.base_dir.mkdir(parents=True)
    recorded.made_with_file.write_text(json.dumps({"root": "/", "version": "3.10.8"}))
    assert recorded.installation() == Installation(HOST)
    monkeypatch.setenv("FLEETBUS_RABBITMQ_ROOT", str(tmp_path / "elsewhere"))
    assert LocalNode(recorded.base_dir).installation() == Installation(tmp_path / "elsewhere")


def test_a_missing_installation_names_the_fix(tmp_path: Path) -> None:
    node = LocalNode(tmp_path / "broker", rabbitmq=Installation(tmp_path / "no-root"))
    with pytest.raises(LocalNodeError, match=r"not installed in the root .*scripts/setup"):
        node.up(timeout=10)
    assert not os.path.exists(node.pid_file)
