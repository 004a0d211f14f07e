"""What can be checked of a command that is not run here: its parser, without running it.

- ``fleetbus ...``: the console script's own (click) parser resolves the subcommand and reads
  every argument and option, types and choices included, and stops before the command runs;
- ``docker compose ...``: the services and profiles it names are compose.yaml's, and a command it
  runs in a service (``run --rm api fleetbus ...``) is checked in turn;
- ``python -m bench...``: the benchmark's own argparse parser reads the arguments, and the run
  stops there;
- ``pip install 'fleetbus[EXTRA]'`` and ``pip install PACKAGE``: the extra exists, or the package
  is one of the project's extras or outside peers (``tests/peers/requirements.in``);
- ``bash scripts/NAME``: the script exists;
- ``sslyze ...``: its options are the pinned sslyze's (``.venv-peers``), its targets HOST:PORT;
- ``schemathesis ... run ...``: its options are the pinned schemathesis's;
- shell builtins (``export``, a function definition, ``cp``): nothing to parse.

Any other program has no check here: the test says so, so that one is added with its command.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import runpy
import shlex
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any
from unittest import mock

import typer
import yaml

from fleetbus.cli import app

ROOT = Path(__file__).resolve().parents[2]
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
SHELL_BUILTINS = frozenset({"export", "cp", "cd", "mkdir", "rm", "source", "."})


def words(command: str) -> list[str]:
    """The program and its arguments: shell words, comments, leading ``VAR=value`` assignments and a
    trailing ``&`` left out."""
    argv = shlex.split(command, comments=True)
    while argv and ASSIGNMENT.match(argv[0]):
        argv.pop(0)
    if argv and argv[-1] == "&":
        argv.pop()
    return argv


def fleetbus_path(args: list[str]) -> tuple[list[str], dict[str, Any]]:
    """The subcommand path ``fleetbus ARGS`` resolves to and its parameters, as the console script's
    parser reads them; its error (a click usage error) when it refuses them. Nothing runs."""
    group = typer.main.get_command(app)
    context = group.make_context("fleetbus", list(args))
    command: Any = group
    path: list[str] = []
    while hasattr(command, "resolve_command"):
        rest = [*context._protected_args, *context.args]
        if not rest:
            break
        name, command, rest = command.resolve_command(context, rest)
        path.append(name)
        context = command.make_context(name, rest, parent=context)
    return path, dict(context.params)


def check_fleetbus(args: list[str]) -> str | None:
    try:
        fleetbus_path(args)
    except Exception as error:  # click's usage errors, and typer's
        message = error.format_message() if hasattr(error, "format_message") else str(error)
        return f"fleetbus {shlex.join(args)}: {message}"
    return None


def compose_file() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "compose.yaml").read_text())


def check_docker(args: list[str]) -> str | None:
    if args[:1] != ["compose"]:
        return f"docker {args[:1]}: only `docker compose` is checked here"
    services: dict[str, Any] = compose_file()["services"]
    rest = args[1:]
    profiles: list[str] = []
    while rest and rest[0] == "--profile":
        profiles.append(rest[1])
        rest = rest[2:]
    # Compose takes any profile name (`central` names the services that have none): no check
    verb, rest = rest[0], rest[1:]
    if verb == "up":
        named = [word for word in rest if not word.startswith("-")]
        for name in named:
            if name not in services:
                return f"compose.yaml has no service {name!r}"
            wanted = services[name].get("profiles", [])
            if wanted and not set(wanted) & set(profiles):
                return f"service {name!r} is in profiles {wanted}, not in {profiles}"
        return None
    if verb == "run":
        while rest and rest[0].startswith("-"):  # --rm and the like
            rest = rest[1:]
        service, command = rest[0], rest[1:]
        if service not in services:
            return f"compose.yaml has no service {service!r}"
        return check_argv(command) if command else None
    if verb == "cp":
        sources = [word.split(":", 1)[0] for word in rest if ":" in word]
        missing = [name for name in sources if name not in services]
        return f"compose.yaml has no service {missing}" if missing else None
    if verb in ("down", "config", "ps", "logs"):
        return None
    return f"docker compose {verb}: not checked here"


class _Parsed(Exception):
    """Raised by argparse once the arguments are read: the benchmark stops before it runs."""


def check_python_module(module: str, args: list[str]) -> str | None:
    """``python -m MODULE ARGS``: a benchmark's argparse parser reads ARGS (and the run stops right
    there); any other module must at least be importable."""
    if module != "bench" and not module.startswith("bench."):
        import importlib.util

        return None if importlib.util.find_spec(module) else f"no module {module!r}"
    original: Callable[..., argparse.Namespace] = argparse.ArgumentParser.parse_args

    def parse_only(self: argparse.ArgumentParser, *given: Any, **named: Any) -> argparse.Namespace:
        original(self, *given, **named)
        raise _Parsed

    refused = io.StringIO()
    with (
        mock.patch.object(argparse.ArgumentParser, "parse_args", parse_only),
        mock.patch.object(sys, "argv", [module, *args]),
        contextlib.redirect_stderr(refused),
        contextlib.redirect_stdout(io.StringIO()),
    ):
        try:
            runpy.run_module(module, run_name="__main__", alter_sys=False)
        except _Parsed:
            return None
        except SystemExit as exit:
            return f"python -m {module} {shlex.join(args)}: exit {exit.code}: {refused.getvalue().strip()}"
    return f"python -m {module}: its main parsed no arguments before running"


def extras() -> dict[str, list[str]]:
    """The installed fleetbus's extras, each with what it requires."""
    from importlib.metadata import metadata, requires

    found: dict[str, list[str]] = {name: [] for name in metadata("fleetbus").get_all("Provides-Extra") or []}
    for requirement in requires("fleetbus") or []:
        if match := re.search(r"extra == ['\"]([\w-]+)['\"]", requirement):
            found.setdefault(match[1], []).append(requirement)
    return found


def peer_packages() -> set[str]:
    """The outside peers a page may tell a reader to install (``tests/peers/requirements.in``)."""
    lines = (ROOT / "tests" / "peers" / "requirements.in").read_text().splitlines()
    names = (re.split(r"[<>=\[ ;#]", line.strip(), maxsplit=1)[0] for line in lines)
    return {name for name in names if name[:1].isalnum()}


def check_pip(args: list[str]) -> str | None:
    if args[:1] != ["install"]:
        return f"pip {args[:1]}: only `pip install` is checked here"
    known = extras()
    peers = peer_packages()
    for requirement in (word for word in args[1:] if not word.startswith("-")):
        name, _, extra = requirement.partition("[")
        if name == "fleetbus":
            missing = [each for each in extra.rstrip("]").split(",") if each and each not in known]
            if missing:
                return f"fleetbus has no extra {missing}"
        elif name not in peers and not any(
            re.match(re.escape(name) + r"\b", each) for deps in known.values() for each in deps
        ):
            return f"{name} is in none of the project's extras, nor an outside peer (tests/peers)"
    return None


def check_curl(args: list[str]) -> str | None:
    """A request to the HTTP API: its method and path are routes of the API's OpenAPI document."""
    from urllib.parse import urlsplit

    from scripts.docs_hooks import openapi_document

    urls = [word for word in args if "://" in word or word.startswith(("localhost:", "127.0.0.1:"))]
    if len(urls) != 1:
        return f"curl {shlex.join(args)}: expected one URL of the HTTP API"
    method = args[args.index("-X") + 1].lower() if "-X" in args else "get"
    path = urlsplit(urls[0] if "://" in urls[0] else f"http://{urls[0]}").path
    for route, operations in openapi_document()["paths"].items():
        if re.fullmatch(re.sub(r"\\{[^}]+\\}", "[^/]+", re.escape(route)), path) and method in operations:
            return None
    return f"the HTTP API has no {method.upper()} {path}"


def unknown_options(program: str, args: list[str], *command: str) -> list[str]:
    """The ``--options`` in ``args`` that the pinned peer ``program`` (``.venv-peers``) does not
    list in ``program COMMAND --help``."""
    from tests.peers import peer_command

    shown = subprocess.run(
        [peer_command(program), *command, "--help"], capture_output=True, text=True, check=True
    )
    known = set(re.findall(r"(--[\w-]+)", shown.stdout))
    return [word for word in args if word.startswith("--") and word.split("=", 1)[0] not in known]


def check_sslyze(args: list[str]) -> str | None:
    """Every option is one the pinned sslyze knows, and every target HOST:PORT."""
    if unknown := unknown_options("sslyze", args):
        return f"sslyze knows no {unknown}"
    takes_value = {
        "--certinfo_ca_file",
        "--json_out",
        "--targets_in",
        "--cert",
        "--key",
        "--keyform",
        "--mozilla_config",
    }
    targets = [
        word
        for word, before in zip(args, ["", *args[:-1]], strict=True)
        if not word.startswith("-") and before not in {*takes_value, "--pass"}
    ]
    bad = [word for word in targets if not re.fullmatch(r"[\w.-]+:\d+(\{[\w.-]+\})?", word)]
    return f"sslyze targets are HOST:PORT, not {bad}" if bad or not targets else None


def check_schemathesis(args: list[str]) -> str | None:
    """``schemathesis [--config-file F] run URL OPTIONS``: the options are the pinned release's."""
    if "run" not in args:
        return "schemathesis: only `schemathesis run` is checked here"
    at = args.index("run")
    unknown = unknown_options("schemathesis", args[:at])
    unknown += unknown_options("schemathesis", args[at + 1 :], "run")
    if unknown:
        return f"schemathesis knows no {unknown}"
    return None


def check_argv(argv: list[str]) -> str | None:
    """The check this command's program has; a problem, or None when it passed."""
    if not argv:
        return None
    program, args = argv[0], argv[1:]
    name = Path(program).name
    if re.fullmatch(r"\w+\(\)", program) or program in SHELL_BUILTINS:
        return None
    if name == "fleetbus":
        return check_fleetbus(args)
    if name == "docker":
        return check_docker(args)
    if name.startswith("python") and args[:1] == ["-m"] and len(args) > 1:
        return check_python_module(args[1], args[2:])
    if name == "pip":
        return check_pip(args)
    if name == "py-spy":
        return None if any("py-spy" in dep for dep in extras().get("profile", [])) else "py-spy: no extra"
    if name == "curl":
        return check_curl(args)
    if name == "sslyze":
        return check_sslyze(args)
    if name == "schemathesis":
        return check_schemathesis(args)
    if name == "bash" and args and args[0].startswith("scripts/"):
        return None if (ROOT / args[0]).is_file() else f"no {args[0]}"
    return f"{program}: nothing checks this program's arguments here; add a check in tests/docs/checks.py"


def check_without_running(command: str) -> str | None:
    return check_argv(words(command))
