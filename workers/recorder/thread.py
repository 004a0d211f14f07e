"""The recorder on a thread of its own, for the demo and the tests (see :mod:`workers.thread`)."""

from __future__ import annotations

from fleetbus.settings import Settings
from workers.recorder.consumer import MissionLookup, RecorderOptions, RecorderStats
from workers.recorder.runner import RecorderContext, run_recorder
from workers.thread import LoopThread


class RecorderThread(LoopThread[RecorderContext]):
    def __init__(
        self,
        settings: Settings,
        url: str,
        options: RecorderOptions | None = None,
        missions: MissionLookup | None = None,
    ) -> None:
        super().__init__(
            lambda stop, started: run_recorder(settings, url, options, stop, started, missions),
            "fleetbus-recorder",
        )

    def stats(self) -> RecorderStats:
        return self.context.consumer.stats if self.context else RecorderStats()
