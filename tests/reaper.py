"""Stops what a test run left running when the run itself is killed.

The private RabbitMQ nodes (and their epmd) that tests start run in sessions of their own, so that
a test can kill them for real; the fixtures stop them when the run ends. A run that is killed
(SIGKILL, a CI timeout) never gets there, and its nodes would run on, holding ports and memory on
a shared machine. The run's controlling process therefore starts this watcher:

    python -m tests.reaper PID FOLDER SECONDS

It waits until process PID is gone, then kills every process whose working folder or ``HOME`` is
under FOLDER (the run's temporary folder, where every test node lives; a node's epmd keeps only the
``HOME`` it was started with), twice, SECONDS apart (xdist's workers may outlive their
controller by a moment).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import psutil

#: How often the watched process is looked for, and the pause between the two sweeps.
POLL_S = 1.0
SECOND_SWEEP_AFTER_S = 5.0


def start(
    pid: int, folder: Path, second_sweep_after: float = SECOND_SWEEP_AFTER_S
) -> subprocess.Popen[bytes]:
    """The watcher, in a session of its own: what kills the run's process group leaves it."""
    return subprocess.Popen(
        [sys.executable, "-m", "tests.reaper", str(pid), str(folder), str(second_sweep_after)],
        cwd=Path(__file__).resolve().parent.parent,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def _under(process: psutil.Process, folder: Path) -> bool:
    try:
        places = [process.cwd(), process.environ().get("HOME", "/nowhere")]
    except (psutil.Error, OSError):
        return False
    return any(Path(place).is_relative_to(folder) for place in places)


def sweep(folder: Path) -> int:
    """Kill every process working under ``folder``; how many there were."""
    found = [p for p in psutil.process_iter() if _under(p, folder)]
    for process in found:
        try:
            process.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(found, timeout=10)
    return len(found)


def main(pid: int, folder: Path, second_sweep_after: float) -> None:
    while psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
        time.sleep(POLL_S)
    sweep(folder)
    time.sleep(second_sweep_after)
    sweep(folder)


if __name__ == "__main__":
    main(int(sys.argv[1]), Path(sys.argv[2]).resolve(), float(sys.argv[3]))
