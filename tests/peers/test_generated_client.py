"""A client generated from the OpenAPI document `fleetbus api` serves, by a generator people use
(openapi-python-client), as an outside program: it logs in, lists hazards and gets each refusal as
the document's typed Problem. The generator must take the whole document without a warning."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

from tests.peers import PEERS, PEERS_VENV, peer_command, peer_python
from tests.peers.served_api import PASSWORD, served_api
from tests.support import Bus


def generate_client(base: str, folder: Path) -> Path:
    """The package ``fleetbus_client`` in ``folder``, generated from the served document."""
    package = folder / "fleetbus_client"
    generator = peer_command("openapi-python-client")
    command = [str(generator), "generate", "--url", f"{base}/openapi.json", "--meta", "none"]
    command += ["--output-path", str(package), "--fail-on-warning"]
    # its post hooks format the code with ruff, which .venv-peers has
    env = {**os.environ, "PATH": f"{PEERS_VENV / 'bin'}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "Warning" not in done.stdout, done.stdout + done.stderr
    return package


def test_a_generated_client_logs_in_lists_hazards_and_gets_typed_problems(bus: Bus, tmp_path: Path) -> None:
    with served_api(bus, ["operator", "guest"]) as api:
        package = generate_client(api.base, tmp_path)
        operator, guest = api.names["operator"], api.names["guest"]
        done = subprocess.run(
            [str(peer_python()), str(PEERS / "generated_client_program.py"), api.base, operator, guest],
            input=json.dumps({operator: PASSWORD, guest: PASSWORD}),  # passwords never in argv
            env={**os.environ, "PYTHONPATH": str(package.parent)},
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 0, done.stdout + done.stderr
    seen = json.loads(done.stdout)
    assert seen["hazards"] == {"type": "list", "count": 0}
    assert seen["wrong_password"] == {
        "type": "Problem",
        "status": 401,
        "title": "Unauthorized",
        "detail": "wrong user name or password",
        "instance": "/auth/token",
        "errors": [],
    }
    assert seen["role_refused"] == {
        "type": "Problem",
        "status": 403,
        "title": "Forbidden",
        "detail": "role guest may not do this; it needs admin or operator or supervisor",
        "instance": "/hazards",
        "errors": [],
    }
    bad_offset = seen["bad_offset"]
    assert (bad_offset["type"], bad_offset["status"], bad_offset["errors"]) == (
        "Problem",
        422,
        [{"loc": ["query", "offset"], "type": "greater_than_equal"}],
    )
    assert bad_offset["detail"].startswith("query.offset: Input should be greater than or equal to 0")
