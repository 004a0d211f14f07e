"""The recorder on a thread of its own, for the demo and the tests (see :mod:`fleetbus_dev.worker_thread`)."""

from __future__ import annotations

from fleetbus.settings import Settings
from fleetbus.workers.recorder.consumer import MissionLookup, RecorderOptions, RecorderStats
from fleetbus.workers.recorder.runner import RecorderContext, recorder_options, run_recorder
from fleetbus_dev.worker_thread import LoopThread


class RecorderThread(LoopThread[RecorderContext]):
    def __init__(
        self,
        settings: Settings,
        url: str,
        options: RecorderOptions | None = None,
        missions: MissionLookup | None = None,
    ) -> None:
        options = options or recorder_options(settings)
        super().__init__(
            lambda stop, started: run_recorder(settings, url, options, stop, started, missions),
            "fleetbus-recorder",
        )

    def stats(self) -> RecorderStats:
        return self.context.consumer.stats if self.context else RecorderStats()
