"""The log format of fleetbus's long-running processes (the workers, the recorder)."""

from __future__ import annotations

import logging


def configure_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    for noisy in ("aiormq", "aio_pika", "httpx", "pika"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
