"""compose.yaml as Docker Compose itself reads it: `docker-compose config` (Compose 2, the parser
`docker compose up` uses; it needs no engine), with every profile. The file is valid under the
Compose Specification once its required variables are set, a secret among them reaches no
container's command line, and each one left unset is refused by name before anything would
start."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.peers import ROOT, peer_command

COMPOSE = ROOT / "compose.yaml"
#: The variables compose.yaml requires (``${NAME:?why}``).
REQUIRED = sorted(set(re.findall(r"\$\{(\w+):\?", COMPOSE.read_text())))
#: The one required variable that is no secret: a site's name is on its command line.
NOT_SECRET = {"FLEETBUS_SITE_NAME"}


def _config(tmp_path: Path, variables: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    """Compose's ``config`` on the checkout's compose.yaml, with only ``variables`` from the
    environment (nothing of the shell's FLEETBUS_*)."""
    env = {"PATH": os.environ["PATH"], "HOME": str(tmp_path), **variables}
    command = [str(peer_command("docker-compose")), "--project-directory", str(ROOT), "-f", str(COMPOSE)]
    return subprocess.run(
        [*command, "--profile", "*", "config", *args], env=env, capture_output=True, text=True, timeout=60
    )


def test_compose_accepts_the_file_and_no_secret_reaches_a_command_line(tmp_path: Path) -> None:
    assert "FLEETBUS_BROKER_PASSWORD" in REQUIRED, "the variables were found"
    marked = {name: f"marker-{name.lower()}" for name in REQUIRED}
    shown = _config(tmp_path, marked, "--format", "json")
    assert shown.returncode == 0, shown.stderr
    services: dict[str, Any] = json.loads(shown.stdout)["services"]
    assert {"rabbitmq", "worker", "api", "site-up"} <= set(services)
    for name, service in services.items():
        argv = json.dumps([service.get(key) for key in ("command", "entrypoint", "healthcheck")])
        for variable, marker in marked.items():
            if variable not in NOT_SECRET:
                assert marker not in argv, f"{variable} is on the command line of {name}"


@pytest.mark.parametrize("missing", REQUIRED)
def test_compose_refuses_the_file_naming_a_required_variable_left_unset(tmp_path: Path, missing: str) -> None:
    refused = _config(tmp_path, {name: "set" for name in REQUIRED if name != missing}, "--quiet")
    assert refused.returncode != 0
    assert f"required variable {missing} is missing a value" in refused.stderr
