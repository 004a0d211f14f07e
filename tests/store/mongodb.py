"""A MongoDB for tests: ``FLEETBUS_MONGODB_URL`` when set, else mongoeco's wire-protocol server.

mongoeco needs Python 3.13, so its server runs as a subprocess from the venv ``.venv-mongoeco``
(``scripts/setup`` creates it). Import the ``mongodb_url`` fixture from here into a conftest;
every conftest that does shares one server process.
"""

from __future__ import annotations

import os
import selectors
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
MONGOECO_PYTHON = PROJECT_ROOT / ".venv-mongoeco" / "bin" / "python"
LAUNCHER = Path(__file__).with_name("mongoeco_server.py")
START_DEADLINE = 60.0
"""Generous: a cold Python 3.13 import of mongoeco on a loaded 2-core machine."""
NO_MONGODB = "no MongoDB: FLEETBUS_MONGODB_URL is unset and .venv-mongoeco (Python 3.13) is missing"


class MongoecoServer:
    """mongoeco's wire server on 127.0.0.1, on the port it picked and printed."""

    def __init__(self, log_path: Path) -> None:
        self.log_path = log_path
        self._process: subprocess.Popen[str] | None = None

    def start(self, deadline: float = START_DEADLINE, port: int = 0, path: Path | None = None) -> str:
        """Start on ``port`` (0: any), in memory or, with ``path``, on a data file that outlives it."""
        command = [str(MONGOECO_PYTHON), str(LAUNCHER), str(port)]
        if path is not None:
            command += ["--path", str(path)]
        # stderr to a file: a pipe nobody reads would block the server once it fills
        with self.log_path.open("a") as log:
            self._process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log, text=True)
        end = time.monotonic() + deadline
        port = self._read_port(end)
        self._await_connection(port, end)
        return f"mongodb://127.0.0.1:{port}/"

    def _read_port(self, end: float) -> int:
        assert self._process is not None and self._process.stdout is not None
        with selectors.DefaultSelector() as selector:
            selector.register(self._process.stdout, selectors.EVENT_READ)
            if not selector.select(max(0.0, end - time.monotonic())):
                self._fail("printed no port in time")
        line = self._process.stdout.readline().strip()  # one flushed line, or "" at exit
        if not line.isdigit():
            self._fail(f"printed {line!r} instead of its port")
        return int(line)

    def _await_connection(self, port: int, end: float) -> None:
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                return
            except OSError:
                if time.monotonic() > end:
                    self._fail(f"does not accept connections on port {port}")
                time.sleep(0.05)

    def _fail(self, what: str) -> None:
        self.stop()
        log = self.log_path.read_text(errors="replace")[-2000:]
        pytest.fail(f"mongoeco's server {what}; its log ({self.log_path}):\n{log}")

    def kill(self) -> None:
        """SIGKILL the server, as a crash would."""
        if self._process is not None:
            self._process.kill()
            self._process.wait(10)
            if self._process.stdout is not None:
                self._process.stdout.close()
            self._process = None

    def stop(self) -> None:
        if self._process is None:
            return
        self._process.terminate()
        try:
            self._process.wait(10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(10)
        if self._process.stdout is not None:
            self._process.stdout.close()
        self._process = None


_shared: MongoecoServer | None = None
_shared_url = ""
_users = 0


@contextmanager
def shared_mongoeco(log_dir: Path) -> Iterator[str]:
    """One server per test session, however many conftests register the fixture."""
    global _shared, _shared_url, _users
    if _shared is None:
        server = MongoecoServer(log_dir / "mongoeco.log")
        _shared_url = server.start()
        _shared = server
    _users += 1
    try:
        yield _shared_url
    finally:
        _users -= 1
        if _users == 0:
            _shared.stop()
            _shared = None


@pytest.fixture(scope="session")
def mongodb_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A MongoDB server URL without a database; skips, saying why, when there is none."""
    if os.environ.get("FLEETBUS_MONGODB_URL"):
        yield os.environ["FLEETBUS_MONGODB_URL"]
        return
    if not MONGOECO_PYTHON.exists():
        pytest.skip(NO_MONGODB)
    with shared_mongoeco(tmp_path_factory.mktemp("mongoeco")) as url:
        yield url
