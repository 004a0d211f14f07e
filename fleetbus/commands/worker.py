"""``fleetbus worker``: the workers in the foreground until SIGTERM or Ctrl-C."""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated

import typer

from fleetbus.context import endpoint, settings
from workers.runner import run_worker


def worker(
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="log every batch")] = False,
) -> None:
    """Validate, store and fan out every event; stop cleanly on SIGTERM or Ctrl-C."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("aiormq").setLevel(logging.WARNING)
    logging.getLogger("aio_pika").setLevel(logging.WARNING)
    asyncio.run(run_worker(settings(), endpoint()))
