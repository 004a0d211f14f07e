"""The recorder as a child process of ``fleetbus worker``.

The recorder and the workers used to share one event loop, and under telemetry the recorder's
inserts sat in front of every hazard: the hazard p50 went from 12 ms to 250 ms (``python -m bench
--only hazard,hazard-recorder``). In a process of its own the recorder costs the workers nothing
but a share of the CPU. The child dies with its parent: it asks the kernel itself, first thing
(``PR_SET_PDEATHSIG``), so a worker killed with SIGKILL leaves no recorder behind; a recorder that
dies is started again after a backoff.

The child arranges its own death signal rather than the parent doing it between fork and exec
(``preexec_fn``): the worker runs threads (the store's, asyncio's executors), and code run in a
forked child of a threaded process can deadlock on a lock another thread held at the fork.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import os
import signal
import sys
import time

from fleetbus.broker.retry import Backoff, Stopped, async_retrying
from fleetbus.broker.urls import without_password

log = logging.getLogger("fleetbus.recorder")

PR_SET_PDEATHSIG = 1
STOP_TIMEOUT_S = 30.0
HEALTHY_AFTER_S = 60.0
"""A recorder that ran this long before it died is restarted at once, not after a long backoff."""
RESTART_BACKOFF = Backoff(initial=1.0, maximum=30.0, jitter=0.5)
PARENT_ENV = "FLEETBUS_DIE_WITH_PARENT"
"""Set by the worker for its recorder child: the pid of the parent it must not outlive."""
#: The worker's secrets its recorder child is not given: it logs in as ``fleetbus-recorder`` with
#: the password kept in the data folder, so of a broker URL it needs the address alone.
NOT_FOR_THE_RECORDER = frozenset({"FLEETBUS_BROKER_PASSWORD", "FLEETBUS_API_SECRET"})
#: The one URL whose password it needs: the store's.
STORE_URL = "FLEETBUS_MONGODB_URL"


def recorder_environment(environ: dict[str, str] | os._Environ[str], parent: int) -> dict[str, str]:
    """The environment of the worker's recorder child: the worker's, with no broker password (the
    ``fleetbus`` account's, the administrator's) where ``ps e`` or ``/proc`` would show it."""
    # the development broker's password stays when no URL names the broker: the child finds the
    # broker by it as the worker did (without it, it would make a new one and restart the broker)
    given = any(environ.get(name) for name in ("FLEETBUS_SERVICE_URL", "FLEETBUS_AMQP_URL"))
    kept = NOT_FOR_THE_RECORDER if given else NOT_FOR_THE_RECORDER - {"FLEETBUS_BROKER_PASSWORD"}
    env = {name: value for name, value in environ.items() if name not in kept}
    for name, value in env.items():
        if name.startswith("FLEETBUS_") and name.endswith("_URL") and name != STORE_URL and "@" in value:
            env[name] = without_password(value)
    env[PARENT_ENV] = str(parent)
    return env


class RecorderExited(Exception):
    """The recorder process ended on its own (a crash); it is started again after a backoff."""


def die_with_parent() -> None:
    """In a child started by :func:`run_recorder_process`: ask the kernel for SIGTERM when the
    parent ends, and end now if the parent is already gone (it died before we asked)."""
    expected = os.environ.pop(PARENT_ENV, None)
    if expected is None or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != int(expected):
        raise SystemExit(f"the worker {expected} that started this recorder is gone")


def recorder_command(verbose: bool) -> list[str]:
    return [sys.executable, "-m", "fleetbus", "recorder", "run", *(["--verbose"] if verbose else [])]


async def _run_once(stop: asyncio.Event, verbose: bool) -> None:
    """One recorder process, until ``stop`` (then SIGTERM it) or until it exits by itself: after a
    healthy run it returns (restart at once), after a short one it raises :class:`RecorderExited`."""
    # a session of its own: Ctrl-C in the terminal reaches the worker alone, which stops the child
    child = await asyncio.create_subprocess_exec(
        *recorder_command(verbose),
        env=recorder_environment(os.environ, os.getpid()),
        start_new_session=True,
    )
    log.info("recorder started as process %d", child.pid)
    started = time.monotonic()
    exited = asyncio.create_task(child.wait())
    stopping = asyncio.create_task(stop.wait())
    await asyncio.wait({exited, stopping}, return_when=asyncio.FIRST_COMPLETED)
    stopping.cancel()
    if not exited.done():
        child.send_signal(signal.SIGTERM)
        try:
            await asyncio.wait_for(exited, STOP_TIMEOUT_S)
        except asyncio.TimeoutError:
            log.error("recorder %d did not stop within %.0f s; killing it", child.pid, STOP_TIMEOUT_S)
            with contextlib.suppress(ProcessLookupError):
                child.kill()
            await exited
        return
    status = exited.result()
    if time.monotonic() - started > HEALTHY_AFTER_S:
        log.error("recorder %d exited with status %s; starting it again", child.pid, status)
        return
    raise RecorderExited(f"recorder {child.pid} exited with status {status}")


async def run_recorder_process(stop: asyncio.Event, verbose: bool = False) -> None:
    """Keep ``fleetbus recorder run`` running beside the workers until ``stop``; then SIGTERM it."""
    while not stop.is_set():
        restarts = async_retrying(
            "the recorder process", on=RecorderExited, backoff=RESTART_BACKOFF, stop=stop, logger=log
        )
        try:
            await restarts(_run_once, stop, verbose)
        except Stopped:
            return
