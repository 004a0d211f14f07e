"""What a process costs, read from /proc: CPU time and resident memory, sampled while work runs."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime


def rss_megabytes(pid: int, field: str = "VmRSS") -> float:
    """Resident memory now (``VmRSS``), or its peak since the process started (``VmHWM``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    return 0.0


class Watch:
    """CPU share and resident memory of processes, sampled on a thread while something runs."""

    def __init__(self, pids: dict[str, int], every: float = 0.5) -> None:
        self._pids = pids
        self._every = every
        self._stop = threading.Event()
        self.rss: dict[str, list[float]] = {name: [] for name in pids}
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.wait(self._every):
            for name, pid in self._pids.items():
                self.rss[name].append(rss_megabytes(pid))

    def measure(self, action: Callable[[], None]) -> dict[str, float]:
        """Run ``action``; the CPU share (% of one core) of each process meanwhile."""
        cpu = {name: cpu_seconds(pid) for name, pid in self._pids.items()}
        started = time.monotonic()
        self._thread.start()
        try:
            action()
        finally:
            self._stop.set()
            self._thread.join()
        wall = time.monotonic() - started
        return {name: 100 * (cpu_seconds(pid) - cpu[name]) / wall for name, pid in self._pids.items()}
