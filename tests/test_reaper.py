"""A killed test run leaves no test node running: its watcher (``tests/reaper.py``) kills what
works under the run's folder once the run is gone, and nothing else."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import psutil

from tests import reaper
from tests.support import wait_for


def _sleeper(cwd: Path, home: Path | None = None) -> subprocess.Popen[bytes]:
    env = {**os.environ, "HOME": str(home)} if home else None
    return subprocess.Popen(["sleep", "600"], cwd=cwd, env=env, start_new_session=True)


def test_the_processes_of_a_killed_run_are_killed_and_no_other(tmp_path: Path) -> None:
    run, elsewhere = tmp_path / "run", tmp_path / "elsewhere"
    (run / "node").mkdir(parents=True)
    elsewhere.mkdir()
    node = _sleeper(run / "node")  # a node's VM works in its folder
    epmd = _sleeper(elsewhere, home=run / "node")  # its epmd keeps only its HOME
    other = _sleeper(elsewhere)
    pytest_run = _sleeper(elsewhere)
    watcher = reaper.start(pytest_run.pid, run, second_sweep_after=0.1)
    try:
        assert node.poll() is None and epmd.poll() is None
        pytest_run.kill()
        pytest_run.wait()
        gone = lambda: node.poll() is not None and epmd.poll() is not None  # noqa: E731
        wait_for(gone, 30, "the run's processes killed")
        assert watcher.wait(30) == 0, "both sweeps done"
        assert other.poll() is None, "a process outside the run's folder is left alone"
    finally:
        for process in (node, epmd, other, pytest_run):
            process.kill()
            process.wait()
        if psutil.pid_exists(watcher.pid):
            watcher.kill()
