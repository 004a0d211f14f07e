"""A long-running process without the command line's weight: the command checks its options, then
replaces itself (``exec``: the same process id, so the same signals reach it and a death signal
asked for stays) with ``python -m MODULE``, which imports only what the work needs.

What the command resolved goes to the new image through an inherited pipe, as JSON: it may hold
a password, which must not appear in the process's arguments (``ps``) or environment.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

#: A pipe's buffer on Linux; the launch is written whole before the ``exec``, so it must fit.
PIPE_BUFFER = 65536


def exec_module(module: str, launch: bytes) -> NoReturn:
    """Replace this process with ``python -m module --launch-fd N``, ``launch`` waiting in the pipe."""
    if len(launch) >= PIPE_BUFFER:
        raise ValueError(f"the options of {module} are too long ({len(launch)} bytes)")
    reading, writing = os.pipe()
    os.write(writing, launch)
    os.close(writing)
    os.set_inheritable(reading, True)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, "-m", module, "--launch-fd", str(reading)])


def read_launch(prog: str, description: str, argv: Sequence[str] | None = None) -> bytes:
    """What :func:`exec_module` handed this process."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--launch-fd", type=int, required=True, help="the pipe the launch is read from")
    args = parser.parse_args(argv)
    with os.fdopen(args.launch_fd, "rb") as pipe:
        return pipe.read()
