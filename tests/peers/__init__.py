"""Outside peers: tools and clients nobody on the project wrote, that check fleetbus's published
contracts (the OpenAPI and AsyncAPI documents, the TLS listeners). ``scripts/setup`` installs them
when ``FLEETBUS_WITH_PEERS=1`` (``scripts/test`` sets it): the Python ones in ``.venv-peers``, the
Node.js ones in ``tests/peers/node_modules``, each pinned in its lock file here."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PEERS = Path(__file__).resolve().parent
PEERS_VENV = ROOT / ".venv-peers"
NODE_MODULES = PEERS / "node_modules"

_INSTALL = "install the outside peers: FLEETBUS_WITH_PEERS=1 bash scripts/setup"


def peer_command(name: str) -> Path:
    """A command of ``.venv-peers`` (``schemathesis``, ``sslyze``, ``openapi-python-client``,
    ``docker-compose``); fails the test, naming the fix, when the peers are not installed."""
    path = PEERS_VENV / "bin" / name
    if not path.exists():
        pytest.fail(f"{path} is missing: {_INSTALL}", pytrace=False)
    return path


def peer_python() -> Path:
    return peer_command("python")


def node_module_file(path: str) -> Path:
    """A file of a package in ``tests/peers/node_modules`` (``axe-core/axe.min.js``)."""
    found = NODE_MODULES / path
    if not found.is_file():
        pytest.fail(f"{found} is missing: {_INSTALL}", pytrace=False)
    return found


def java() -> str:
    """The ``java`` binary, which runs the Nu Html Checker (``vnu-jar`` among the Node.js peers)."""
    found = shutil.which("java")
    if found is None:
        pytest.fail(f"no java to run the Nu Html Checker: {_INSTALL}", pytrace=False)
    return found


def node() -> str:
    """The ``node`` binary, with ``tests/peers/node_modules`` installed beside it."""
    found = shutil.which("node")
    if found is None or not NODE_MODULES.is_dir():
        pytest.fail(f"node or {NODE_MODULES} is missing: {_INSTALL}", pytrace=False)
    return found
