"""On central: each mission the API created or changed goes to every site, in the background.

The request that changed a mission does not wait for the sites. Each changed mission waits here,
its newest version only (one per mission, so what waits is bounded by the number of missions),
until central's broker confirmed it for every site; while the broker does not take it, it is
tried again with backoff (up to ``MAXIMUM_WAIT_S`` between tries), a warning logged at the first
failure and every ``WARN_EVERY`` after. What still waits when the API stops is logged by mission
id: `fleetbus sites sync SITE` sends every mission again."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable

from fleetbus.publishers.backoff import Backoff
from fleetbus.workers.store.missions import Mission

log = logging.getLogger("fleetbus.api")

MAXIMUM_WAIT_S = 30.0
WARN_EVERY = 10
BACKOFF = Backoff(initial=0.5, maximum=MAXIMUM_WAIT_S, jitter=0.5)


class MissionsToSites:
    def __init__(self, send: Callable[[Mission], Awaitable[object]], backoff: Backoff = BACKOFF) -> None:
        self._send = send
        self._backoff = backoff
        self._waiting: dict[str, Mission] = {}
        self._wake = asyncio.Event()
        self._task: asyncio.Task[None] | None = None

    @property
    def waiting(self) -> int:
        """Missions changed but not yet confirmed to the sites."""
        return len(self._waiting)

    async def changed(self, mission: Mission) -> None:
        """Send ``mission`` as it is now (a version waiting for it is replaced)."""
        self._waiting[mission.mission_id] = mission
        self._wake.set()

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="fleetbus-missions-to-sites")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self._waiting:
            log.warning(
                "%d missions changed but not sent to the sites (%s): run `fleetbus sites sync`",
                len(self._waiting),
                ", ".join(sorted(self._waiting)),
            )

    async def _run(self) -> None:
        failures = 0
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._waiting:
                mission_id, mission = next(iter(self._waiting.items()))
                try:
                    await self._send(mission)
                except Exception as error:  # the broker away: this version waits for the next try
                    if failures % WARN_EVERY == 0:
                        log.warning(
                            "mission %s not sent to the sites yet (%s: %s); trying again",
                            mission_id,
                            type(error).__name__,
                            error,
                        )
                    await asyncio.sleep(self._backoff.delay(failures))
                    failures += 1
                    continue
                if failures:
                    log.info("missions reach the sites again")
                failures = 0
                if self._waiting.get(mission_id) is mission:  # not changed again meanwhile
                    del self._waiting[mission_id]
