"""The ROS side's log: read from its pipe as fast as it is written, kept within its bound, 0600."""

from __future__ import annotations

import errno
import re
import stat
import subprocess
import sys
import threading
from pathlib import Path

from fleetbus.publishers.ros.side_log import BoundedLog, copy_lines

LINES = 20_000  # about 250 KB: far more than a pipe's buffer and the bound


def noisy_process() -> subprocess.Popen[bytes]:
    """A process that writes LINES numbered lines on stderr as fast as it can, then ends."""
    script = f"import sys\nfor n in range({LINES}): sys.stderr.write(f'a warning, number {{n}}\\n')"
    return subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE)


def copied(process: subprocess.Popen[bytes], into: BoundedLog) -> int:
    """Copy ``process``'s stderr into ``into`` until it ends (it must end: never blocked on its
    pipe); the lines dropped."""
    assert process.stderr is not None
    dropped: list[int] = []
    copy = threading.Thread(target=copy_lines, args=(process.stderr, into, lambda: dropped.append(1)))
    copy.start()
    assert process.wait(60) == 0
    copy.join(60)
    assert not copy.is_alive()
    return len(dropped)


def test_a_side_that_writes_a_lot_keeps_its_newest_lines_within_the_bound(tmp_path: Path) -> None:
    log = BoundedLog(tmp_path / "ros-side.log", 4096)
    assert copied(noisy_process(), log) == 0
    log.close()
    files = [log.older, log.path]
    assert [f.stat().st_size <= 4096 for f in files] == [True, True]
    assert [stat.S_IMODE(f.stat().st_mode) for f in files] == [0o600, 0o600]
    text = b"".join(f.read_bytes() for f in files)
    kept = [int(n) for n in re.findall(rb"a warning, number (\d+)\n", text)]
    assert kept == list(range(LINES - len(kept), LINES)) and len(kept) > 100, "the newest, every one"
    assert text.endswith(f"a warning, number {LINES - 1}\n".encode())


class FullDisk(BoundedLog):
    def write(self, data: bytes) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")


def test_lines_that_cannot_be_written_are_counted_and_the_pipe_still_read(tmp_path: Path) -> None:
    assert copied(noisy_process(), FullDisk(tmp_path / "ros-side.log", 4096)) == LINES


def test_a_log_over_the_bound_keeps_its_newest_bytes_as_the_older_file(tmp_path: Path) -> None:
    """An older bridge's unbounded log (made 0644 by a wider umask), or a bound since lowered."""
    path = tmp_path / "ros-side.log"
    path.write_bytes(b"".join(f"line {n}\n".encode() for n in range(2000)))
    path.chmod(0o644)
    log = BoundedLog(path, 1000)
    log.write(b"the first line since\n")
    log.close()
    assert path.read_bytes() == b"the first line since\n"
    older = log.older.read_bytes()
    assert len(older) == 1000 and older.endswith(b"line 1999\n")
    assert [stat.S_IMODE(f.stat().st_mode) for f in (log.older, path)] == [0o600, 0o600]
