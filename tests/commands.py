"""`fleetbus` commands as typed, run in the test's own process: the same Typer app, environment
and exit code as a shell's, without the interpreter's start (a second or two a command)."""

from __future__ import annotations

from dataclasses import dataclass

from typer.testing import CliRunner

from fleetbus.cli import app
from tests.support import Bus


@dataclass(frozen=True)
class Ran:
    returncode: int
    stdout: str
    stderr: str


def fleetbus(bus: Bus, *args: str) -> Ran:
    """``fleetbus ARGS`` on ``bus`` as its administrator; an exception the command did not turn
    into an exit is raised here."""
    env = {**bus.worker_env(), "COLUMNS": "200"}
    result = CliRunner().invoke(app, list(args), env=env)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return Ran(result.exit_code, result.stdout, result.stderr)
