"""Everything fleetbus writes into its data folder is its owner's only: 0700 folders, 0600 files.

The store holds the argon2 hashes and the sealed broker passwords, the recording every message, the
accounts and API folders secrets, the TLS folder keys: a user of the machine who is not fleetbus's
must not read any of them. The run below writes what a deployment writes (certificates, accounts,
the store, the recording, the API's secret, a robot's personal database), each by the command a
user runs, then every file and folder under the data folder is checked.
"""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from fleetbus.private_files import private_dir, private_file
from fleetbus.schemas.routing import RobotKind
from fleetbus_dev.local_node import LocalNode
from tests.factories import hazard
from tests.support import Bus, wait_for

PASSWORD = "a private files password"


def fleetbus(bus: Bus, *args: str, stdin: str = "") -> None:
    env = {**os.environ, **bus.worker_env()}
    done = subprocess.run(
        [sys.executable, "-m", "fleetbus", *args], env=env, input=stdin, capture_output=True, text=True
    )
    assert done.returncode == 0, f"fleetbus {' '.join(args)}: {done.stdout}{done.stderr}"


def others_may(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode) & 0o077


def test_every_file_fleetbus_writes_in_its_data_folder_is_its_owners_only(
    bus: Bus, tmp_path_factory: pytest.TempPathFactory
) -> None:
    logs = tmp_path_factory.mktemp("logs")  # the test's own files, outside the data folder
    data = bus.settings.data_dir
    data.chmod(0o755)  # as a folder made by hand, before fleetbus first ran, would be
    fleetbus(bus, "certs", "make", "--dir", str(data / "tls"))  # the suite's broker keeps the run's
    fleetbus(bus, "users", "add", "explorer1", "--kind", "explorer")
    bus.accounts.append("explorer1")
    bus.api.delete_user("files-admin")  # broker users are node-wide: one an aborted run left
    bus.accounts.append("files-admin")
    fleetbus(bus, "api", "create-admin", "files-admin", "--password-stdin", stdin=PASSWORD + "\n")
    with open(logs / "worker.log", "wb") as log:
        worker = subprocess.Popen(
            [sys.executable, "-m", "fleetbus", "worker"], env=bus.service_env(), stdout=log, stderr=log
        )
    try:
        robot = bus.robot(bus.add("explorer2", kind=RobotKind.EXPLORER))  # its state in data/robots
        robot.publish("hazard", hazard())
        wait_for(lambda: bus.count("hazard") == 1, what="the hazard stored")
        wait_for(lambda: bool(bus.recorded("hazard")), what="the hazard recorded")
    finally:
        worker.send_signal(signal.SIGINT)
        assert worker.wait(60) == 0, (logs / "worker.log").read_text()[-3000:]

    seen = {path.relative_to(data).as_posix() for path in data.rglob("*")}
    written = ("store.sqlite3", "recording.sqlite3", "api/secret", "tls/ca.key", "accounts/explorer1.url")
    for expected in written:
        assert expected in seen, f"{expected} was not written: {sorted(seen)}"
    assert any(name.startswith("robots/explorer2/") for name in seen), sorted(seen)
    open_to_others = {
        path.relative_to(data).as_posix(): oct(stat.S_IMODE(path.stat().st_mode))
        for path in [data, *data.rglob("*")]
        if others_may(path)
    }
    assert open_to_others == {}


def test_a_private_file_is_never_open_to_others_and_an_existing_one_is_narrowed(tmp_path: Path) -> None:
    made = private_file(tmp_path / "a" / "b" / "secret")
    assert [oct(stat.S_IMODE(p.stat().st_mode)) for p in (tmp_path / "a", made.parent, made)] == [
        "0o700",
        "0o700",
        "0o600",
    ]
    loose = tmp_path / "loose"
    loose.write_text("x")
    loose.chmod(0o644)
    private_file(loose)
    assert others_may(loose) == 0 and loose.read_text() == "x"
    folder = tmp_path / "folder"
    folder.mkdir(mode=0o755)
    folder.chmod(0o755)
    assert others_may(private_dir(folder)) == 0


def test_a_private_nodes_folder_is_its_owners_only(killable_node: LocalNode) -> None:
    """The node's configuration, its administrator's password, its database and its logs, as the
    node and fleetbus wrote them."""
    killable_node.up()
    files = [killable_node.base_dir, *killable_node.base_dir.rglob("*")]
    assert any(path.name == "admin.json" for path in files) and any("mnesia" in path.parts for path in files)
    open_to_others = {
        path.relative_to(killable_node.base_dir).as_posix(): oct(stat.S_IMODE(path.lstat().st_mode))
        for path in files
        if not path.is_symlink() and others_may(path)
    }
    assert open_to_others == {}
