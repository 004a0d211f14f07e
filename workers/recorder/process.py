"""The recorder as a child process of ``fleetbus worker``.

The recorder and the workers used to share one event loop, and under telemetry the recorder's
inserts sat in front of every hazard: the hazard p50 went from 12 ms to 250 ms (``python -m bench
--only hazard,hazard-recorder``). In a process of its own the recorder costs the workers nothing
but a share of the CPU. The child dies with its parent (``PR_SET_PDEATHSIG``), so a worker killed
with SIGKILL leaves no recorder behind; a recorder that dies is started again after a backoff.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import signal
import sys
import time

from workers.backoff import Backoff

log = logging.getLogger("fleetbus.recorder")

PR_SET_PDEATHSIG = 1
STOP_TIMEOUT_S = 30.0
HEALTHY_AFTER_S = 60.0
"""A recorder that ran this long before it died is restarted at once, not after a long backoff."""


def die_with_parent() -> None:
    """In the child, before exec: the kernel sends SIGTERM when the parent thread ends."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def recorder_command(verbose: bool) -> list[str]:
    return [sys.executable, "-m", "fleetbus", "recorder", "run", *(["--verbose"] if verbose else [])]


async def run_recorder_process(stop: asyncio.Event, verbose: bool = False) -> None:
    """Keep ``fleetbus recorder run`` running beside the workers until ``stop``; then SIGTERM it."""
    backoff = Backoff(initial=1.0, maximum=30.0)
    while not stop.is_set():
        # a session of its own: Ctrl-C in the terminal reaches the worker alone, which stops the child
        child = await asyncio.create_subprocess_exec(
            *recorder_command(verbose), preexec_fn=die_with_parent, start_new_session=True
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
        if time.monotonic() - started > HEALTHY_AFTER_S:
            backoff.reset()
        delay = backoff.next_delay()
        status = exited.result()
        log.error("recorder %d exited with status %s; starting it again in %.0f s", child.pid, status, delay)
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(stop.wait(), delay)
