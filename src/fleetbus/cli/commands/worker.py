"""``fleetbus worker``: the workers (and the recorder) in the foreground until SIGTERM or Ctrl-C."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import Annotated

import typer

from fleetbus.cli.context import service_account, settings
from fleetbus.private_files import owner_only_umask
from fleetbus.settings import MAX_INGEST_SHARDS
from fleetbus.workers.logs import configure_logging
from fleetbus.workers.recorder.process import run_recorder_process
from fleetbus.workers.recorder.runner import declare_recording
from fleetbus.workers.runner import run_worker
from fleetbus.workers.signals import stop_on_signals

Run = Callable[[asyncio.Event], Awaitable[None]]


async def run_together(*runs: Run) -> None:
    """Run side by side until a signal; when one ends (or fails), the others are stopped too."""
    stop = asyncio.Event()
    stop_on_signals(stop)

    async def guarded(run: Run) -> None:
        try:
            await run(stop)
        finally:
            stop.set()

    await asyncio.gather(*(guarded(run) for run in runs))


def worker(
    recorder: Annotated[
        bool,
        typer.Option("--recorder/--no-recorder", help="also record everything (a recorder child process)"),
    ] = True,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="log every batch")] = False,
    shards: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=MAX_INGEST_SHARDS,
            help="ingest shards the workers share (default: FLEETBUS_INGEST_SHARDS, 1)",
        ),
    ] = None,
) -> None:
    """Validate, store and fan out every event, and record everything; stop cleanly on SIGTERM or Ctrl-C.

    Runs as the `fleetbus` account only (the recorder as `fleetbus-recorder`): run `fleetbus setup`
    as the administrator once first. Run several to share the ingest: each takes its share of the shards.
    """
    owner_only_umask()  # what it and its recorder write is theirs only (fleetbus.private_files)
    configure_logging(verbose)
    config, url = settings(), service_account()
    if shards is not None:
        config = config.updated(ingest_shards=shards)
    runs: list[Run] = [lambda stop: run_worker(config, url, stop)]
    if recorder:
        asyncio.run(declare_recording(url, cluster=config.cluster))
        runs.append(lambda stop: run_recorder_process(stop, verbose))
    asyncio.run(run_together(*runs))
