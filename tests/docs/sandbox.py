"""A page's commands run as a reader runs them, one after the other, in a sandbox of their own.

The sandbox is what a reader has after ``scripts/setup``, and nothing shared: a fresh virtual
host set up as ``fleetbus setup`` leaves it (``tests.support.fresh_bus``), a fresh data directory,
and a working folder whose top-level entries are the checkout's (linked), so that
``bash scripts/...``, ``.venv/bin/...`` and ``python -m bench`` work as shown while the files a
command writes (``hazard.yaml``, ``evaluation.png``) land in the sandbox. ``fleetbus`` is the
checkout's console script (``.venv/bin`` first on the PATH).

Each command runs in ``bash -c`` with the environment the page's earlier commands left
(``export`` carries on), its standard input empty. A command that runs until stopped (see
``SERVERS``) is started in the background, awaited until it is ready, and stopped with Ctrl-C
(SIGINT) once the page's last command ran; it must still be running then and exit cleanly. Any
other command ending in ``&`` is a job: it runs beside the next commands and must end with status
0 by the page's next ``wait`` (or by its end).

What the test puts in a command, declared here and nowhere else (docs/contributing.md):

- ``PLACEHOLDERS``: a word in capitals that stands for what the reader fills in;
- the API's port: a page shows ``8000``; the sandbox serves the API on a free port, puts it where a
  command says ``8000`` and gives ``fleetbus api`` without ``--port`` that port (tests run side
  by side on one machine);
- ``TYPED``: what a command that asks for a password reads, typed as a reader would.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import urlsplit

import httpx

from fleetbus.publishers.tls import blocking_connection
from fleetbus.workers.store.base import EventQuery
from tests.docs.checks import fleetbus_path, words
from tests.docs.pages import ROOT, Command, Page
from tests.run_tls import run_tls_files
from tests.support import Bus, wait_for

#: The password a page's account is given when a command asks for one (``api create-admin``), and
#: what stands for it in a command (``PASSWORD``).
PASSWORD = "docs-sandbox-Password-1"
API_PORT_SHOWN = "8000"
#: Placeholders a runnable command may hold, with what replaces them (a function of the sandbox).
PLACEHOLDERS: dict[str, Callable[[Sandbox], str]] = {
    "MESSAGE_ID": lambda sandbox: sandbox.last_message_id(),
    "PASSWORD": lambda sandbox: PASSWORD,
}
#: Words in capitals that are what they say, not placeholders.
LITERAL_CAPITALS = frozenset({"GET", "POST", "PUT", "DELETE", "PATCH"})
#: Commands that ask for a password on their terminal, and how many times they ask.
TYPED: dict[tuple[str, ...], int] = {("api", "create-admin"): 2, ("api", "login"): 1}
#: Commands that run until stopped, by their subcommand path: how to tell each is ready.
SERVERS = frozenset({("worker",), ("api",), ("recorder", "run"), ("tail",)})
COMMAND_TIMEOUT_S = 300.0  # `bash scripts/demo`'s setup and demo; most take a second
READY_TIMEOUT_S = 60.0
CAPITALS = re.compile(r"(?<![$\w{])[A-Z][A-Z0-9_]{2,}(?![\w=])")
PUBLISHED = re.compile(r"^published (?P<type>\w+) (?P<id>\S+) as (?P<robot>\S+),", re.MULTILINE)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class Server:
    command: Command
    path: tuple[str, ...]
    params: dict[str, object]
    process: subprocess.Popen[bytes]
    log: Path

    def output(self) -> str:
        return self.log.read_text(errors="replace")[-4000:]


@dataclass
class Sandbox:
    bus: Bus
    folder: Path
    env: dict[str, str]
    api_port: int = field(default_factory=free_port)
    servers: list[Server] = field(default_factory=list)
    jobs: list[Server] = field(default_factory=list)  # ``cmd &`` that ends by itself
    published: list[tuple[str, str, str]] = field(default_factory=list)  # (type, message id, robot)
    tools: dict[str, dict[str, str]] = field(default_factory=dict)  # a program's own environment

    @classmethod
    def make(cls, bus: Bus, tmp_path: Path) -> Sandbox:
        folder = tmp_path / "work"
        folder.mkdir()
        for entry in ROOT.iterdir():
            if entry.name not in (".fleetbus", ".git", "site"):
                (folder / entry.name).symlink_to(entry)
        # where a reader's files are (the default data directory, ./.fleetbus) is the sandbox's
        (folder / ".fleetbus").symlink_to(bus.settings.data_dir, target_is_directory=True)
        bus.service_accounts()  # what `fleetbus setup` (run by `scripts/setup`) made
        # the run's CA and certificates, copied: what `certs make` and `users add --cert` change is
        # the sandbox's, and what they sign the broker trusts
        tls = bus.settings.data_dir / "tls"
        shutil.copytree(run_tls_files().ca.parent, tls, dirs_exist_ok=True)
        env = {
            **{key: value for key, value in bus.worker_env().items() if key != "FLEETBUS_TLS_CA"},
            "FLEETBUS_TLS_DIR": str(tls),
            "PATH": f"{ROOT / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
            # a page's `bash scripts/setup` (or `demo`) must not install the peers and ROS again
            # in the checkout the other tests use (`scripts/test` asks for them)
            "FLEETBUS_WITH_PEERS": "0",
            "FLEETBUS_WITH_ROS": "0",
            "COLUMNS": "160",
            "NO_COLOR": "1",
        }
        sandbox = cls(bus, folder, env)
        sandbox.env["FLEETBUS_API_URL"] = f"http://127.0.0.1:{sandbox.api_port}"
        return sandbox

    # --- what the test puts in a command ---------------------------------------------------------

    def last_message_id(self) -> str:
        assert self.published, "MESSAGE_ID stands for the id `fleetbus publish` printed: publish first"
        return self.published[-1][1]

    def filled(self, command: Command) -> str:
        text = re.sub(rf"\b{API_PORT_SHOWN}\b", str(self.api_port), command.text)
        for word in set(CAPITALS.findall(" ".join(words(text)))) - LITERAL_CAPITALS:
            if word not in PLACEHOLDERS:
                raise AssertionError(
                    f"{command.where}: {word} in `{command.text}` looks like a placeholder: show a value "
                    "that works, or declare it in PLACEHOLDERS (tests/docs/sandbox.py)"
                )
            text = re.sub(rf"\b{word}\b", PLACEHOLDERS[word](self), text)
        return text

    # --- running ------------------------------------------------------------------------------------

    def write_files(self, page: Page) -> None:
        for name, content in page.files.items():
            target = self.folder / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(content)

    def run_page(self, page: Page) -> list[Command]:
        """Every command of the page that runs here, in page order; the ones run."""
        self.write_files(page)
        ran = [command for command in page.commands if command.not_run is None]
        try:
            for command in ran:
                self.run(command)
        except AssertionError as failure:
            logs = "\n".join(
                f"{each.command.where}: `{each.command.text}`:\n{each.output()}"
                for each in (*self.servers, *self.jobs)
            )
            with contextlib.suppress(AssertionError):
                self.stop_servers()
            if logs:
                raise AssertionError(f"{failure}\n\nwhat ran in the background said:\n{logs}") from None
            raise
        self.stop_servers()
        return ran

    def run(self, command: Command) -> None:
        text = self.filled(command)
        argv = words(text)
        path, params = fleetbus_path(argv[1:]) if argv and Path(argv[0]).name == "fleetbus" else ((), {})
        background = text.rstrip().split("#", 1)[0].rstrip().endswith("&")
        if tuple(path) in SERVERS:
            self.start_server(command, text, tuple(path), params)
            return
        if background:
            self.start_job(command, text)
            return
        if text.split("#", 1)[0].strip() == "wait":
            self.wait_jobs(command)
            return
        if argv[:1] == ["curl"] and not any(
            word.startswith("--fail") or re.fullmatch(r"-[a-zA-Z]*f[a-zA-Z]*", word) for word in argv
        ):
            raise AssertionError(
                f"{command.where}: `{command.text}` would exit 0 on an HTTP error: add --fail-with-body"
            )
        stdin = "".join(f"{PASSWORD}\n" * TYPED.get(tuple(path), 0))
        env_file = self.folder.parent / "env"
        script = f'{text}\n__status=$?\nenv -0 > "{env_file}"\nexit $__status\n'
        env = {**self.env, **self.tools.get(argv[0] if argv else "", {})}
        try:
            done = subprocess.run(
                ["bash", "-c", script],
                cwd=self.folder,
                env=env,
                input=stdin,
                capture_output=True,
                text=True,
                timeout=COMMAND_TIMEOUT_S,
                start_new_session=True,  # no terminal: a password is read from standard input
            )
        except subprocess.TimeoutExpired as error:
            raise AssertionError(
                f"{command.where}: `{command.text}` did not end within {COMMAND_TIMEOUT_S:.0f} s:\n"
                f"{(error.stdout or b'')[-3000:]!r}"
            ) from None
        output = done.stdout + done.stderr
        if done.returncode != 0:
            raise AssertionError(
                f"{command.where}: `{command.text}` exited with {done.returncode}:\n{output[-4000:]}"
            )
        if argv and argv[0] not in self.tools:
            self.env = dict(entry.split("=", 1) for entry in env_file.read_text().split("\0") if "=" in entry)
        if tuple(path) == ("publish",):
            self.after_publish(command, output)

    def after_publish(self, command: Command, output: str) -> None:
        """Note the id it printed; with a worker running, wait until it is stored (and recorded): the
        page's next command may read it, as a reader would a moment later."""
        match = PUBLISHED.search(output)
        assert match, f"{command.where}: `fleetbus publish` printed no message id:\n{output}"
        self.published.append((match["type"], match["id"], match["robot"]))
        workers = [server for server in self.servers if server.path == ("worker",)]
        if not workers:
            return
        wait_for(
            lambda: any(
                record.message_id == match["id"]
                for record in self.bus.find(EventQuery(type=match["type"], robot_id=match["robot"]))
            ),
            timeout=READY_TIMEOUT_S,
            what=f"{command.where}: the worker to store {match['type']} {match['id']}",
        )
        if any(server.params.get("recorder") for server in workers):
            wait_for(
                lambda: self.bus.recorded(match["type"], message_id=match["id"]),
                timeout=READY_TIMEOUT_S,
                what=f"{command.where}: the recorder to record {match['type']} {match['id']}",
            )

    # --- what runs until stopped ----------------------------------------------------------------

    def start_server(
        self, command: Command, text: str, path: tuple[str, ...], params: dict[str, object]
    ) -> None:
        argv = shlex.split(text, comments=True)
        if argv and argv[-1] == "&":
            argv.pop()
        assignments = {}
        while argv and re.match(r"^[A-Za-z_]\w*=", argv[0]):
            name, value = argv.pop(0).split("=", 1)
            assignments[name] = value
        if path == ("api",) and "--port" not in argv:
            argv += ["--port", str(self.api_port)]
        log = self.folder.parent / f"server-{len(self.servers)}.log"
        process = subprocess.Popen(
            argv,
            cwd=self.folder,
            env={**self.env, **assignments},
            stdin=subprocess.DEVNULL,
            stdout=log.open("wb"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        server = Server(command, path, params, process, log)
        self.servers.append(server)
        ready = self.readiness(server)

        def up() -> bool:
            if process.poll() is not None:
                raise AssertionError(
                    f"{command.where}: `{command.text}` ended ({process.returncode}) before it was ready:\n"
                    f"{server.output()}"
                )
            return ready()

        wait_for(up, timeout=READY_TIMEOUT_S, what=f"{command.where}: `{command.text}` to be ready")

    def readiness(self, server: Server) -> Callable[[], bool]:
        if server.path == ("worker",):
            count = sum(1 for each in self.servers if each.path == ("worker",))
            recorder = bool(server.params.get("recorder"))
            return lambda: (
                self.live_workers() >= count and (not recorder or self.consumers("fleetbus.recorder") > 0)
            )
        if server.path == ("recorder", "run"):
            return lambda: self.consumers("fleetbus.recorder") > 0
        if server.path == ("api",):
            scheme = "https" if server.params.get("tls") else "http"
            ca = self.bus.settings.data_dir / "tls" / "ca.pem"
            verify: str | bool = str(ca) if scheme == "https" else True
            return lambda: self.answers(f"{scheme}://127.0.0.1:{self.api_port}/health", verify)
        if server.path == ("tail",):
            return lambda: "following" in server.output()
        raise AssertionError(
            f"{server.command.where}: `{server.command.text}` runs in the background, and nothing here "
            "tells when it is ready: add its readiness to Sandbox.readiness (tests/docs/sandbox.py)"
        )

    def live_workers(self) -> int:
        now = datetime.now(timezone.utc)
        leases = self.bus.with_store(lambda store: store.leases.leases("worker:"))
        return sum(1 for lease in leases if lease.expires_at > now)

    def consumers(self, queue: str) -> int:
        connection = blocking_connection(self.bus.admin_url)
        try:
            return connection.channel().queue_declare(queue, passive=True).method.consumer_count
        finally:
            connection.close()

    @staticmethod
    def answers(url: str, verify: str | bool) -> bool:
        try:
            return httpx.get(url, verify=verify, timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    # --- what runs in the background and ends by itself (``cmd &`` ... ``wait``) -----------------

    def start_job(self, command: Command, text: str) -> None:
        """A command ending in ``&`` that is not a server: it runs in ``bash -c`` beside the page's
        next commands, as in a reader's shell, and must have ended with status 0 by the page's
        ``wait`` (or its end)."""
        log = self.folder.parent / f"job-{len(self.jobs)}.log"
        script = text.split("#", 1)[0].rstrip().removesuffix("&")
        process = subprocess.Popen(
            ["bash", "-c", script],
            cwd=self.folder,
            env=self.env,
            stdin=subprocess.DEVNULL,
            stdout=log.open("wb"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.jobs.append(Server(command, (), {}, process, log))

    def wait_jobs(self, command: Command | None = None) -> None:
        """``wait``: every background job ends, each with status 0."""
        problems = []
        for job in self.jobs:
            try:
                status = job.process.wait(COMMAND_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.killpg(job.process.pid, signal.SIGKILL)
                job.process.wait()
                problems.append(
                    f"{job.command.where}: `{job.command.text}` did not end within "
                    f"{COMMAND_TIMEOUT_S:.0f} s:\n{job.output()}"
                )
                continue
            if status != 0:
                problems.append(
                    f"{job.command.where}: `{job.command.text}` exited with {status}:\n{job.output()}"
                )
        self.jobs.clear()
        where = f"{command.where}: " if command is not None else ""
        assert not problems, where + "\n\n".join(problems)

    def stop_servers(self) -> None:
        """Every job waited for; then Ctrl-C to each server, newest first: each must still run, and
        end cleanly."""
        self.wait_jobs()
        problems = []
        for server in reversed(self.servers):
            process = server.process
            if process.poll() is not None:
                problems.append(
                    f"{server.command.where}: `{server.command.text}` had ended ({process.returncode}) "
                    f"before the page's last command:\n{server.output()}"
                )
                continue
            process.send_signal(signal.SIGINT)
            try:
                status = process.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
                problems.append(f"{server.command.where}: `{server.command.text}` ignored Ctrl-C for 30 s")
                continue
            if status not in (0, 130, -signal.SIGINT):
                problems.append(
                    f"{server.command.where}: `{server.command.text}` exited with {status} on Ctrl-C:\n"
                    f"{server.output()}"
                )
        self.servers.clear()
        assert not problems, "\n\n".join(problems)

    def users_made(self) -> list[str]:
        """The broker accounts the page's commands made with a permission in the sandbox's virtual
        host (users are node-wide: they are removed with it)."""
        admin = urlsplit(self.bus.endpoint.amqp_url).username
        kept = {"fleetbus", "fleetbus-recorder", admin}
        return [
            user["name"]
            for user in self.bus.api.list_users()
            if user["name"] not in kept and self.bus.api.get_permissions(self.bus.vhost, user["name"])
        ]
