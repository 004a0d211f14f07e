"""``fleetbus worker`` that dies by SIGKILL right after it dead-letters a message (test code only).

    python -m tests.faulty_worker [worker options]

The fault sits where a crash would double a dead letter: the rejection is done as far as the
worker goes (the reason kept, the message handed to the broker) and nothing after it (the batch's
ack) has happened.
"""

from __future__ import annotations

import os
import signal
import sys
from typing import Any

from fleetbus.cli import app
from fleetbus.workers.ingest import IngestConsumer

_reject = IngestConsumer._reject


async def _reject_then_die(self: IngestConsumer, *args: Any) -> None:
    await _reject(self, *args)
    os.kill(os.getpid(), signal.SIGKILL)


IngestConsumer._reject = _reject_then_die  # type: ignore[method-assign]

if __name__ == "__main__":
    app(["worker", *sys.argv[1:]])
