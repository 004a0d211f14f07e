"""An earlier commit's code, importable beside today's, so a benchmark can run both in one run.

    with baseline_tree("main") as path:
        env = {**os.environ, "PYTHONPATH": str(path)}   # `python -m fleetbus` is now that commit's

The commit is exported with ``git archive`` (the worktree is left alone) and laid out as the
installed package is: the repository's ``fleetbus/`` folder with the design card's folders
(``schemas/``, ``workers/``...) mapped into it as ``pyproject.toml``'s ``package-dir`` says. A path
on PYTHONPATH is found before the editable install's finder, so the child imports that code; its
dependencies come from the same virtual environment.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import tarfile
import tempfile
from collections.abc import Iterator
from pathlib import Path

import tomllib

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def commit_of(ref: str) -> str:
    return subprocess.run(
        ["git", "-C", str(PROJECT_ROOT), "rev-parse", "--short", ref],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


@contextlib.contextmanager
def baseline_tree(ref: str) -> Iterator[Path]:
    """A folder to put on PYTHONPATH that imports ``fleetbus`` as it was at ``ref``."""
    with tempfile.TemporaryDirectory(prefix="fleetbus-baseline-") as folder:
        tree, site = Path(folder, "tree"), Path(folder, "site")
        archive = subprocess.run(
            ["git", "-C", str(PROJECT_ROOT), "archive", "--format=tar", ref],
            check=True,
            capture_output=True,
        ).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(tree, filter="tar")
        config = tomllib.loads((tree / "pyproject.toml").read_text())
        mapped: dict[str, str] = config["tool"]["setuptools"].get("package-dir", {})
        package = site / "fleetbus"
        package.mkdir(parents=True)
        for child in (tree / "fleetbus").iterdir():
            (package / child.name).symlink_to(child)
        for name, source in mapped.items():
            parts = name.split(".")
            if parts[0] == "fleetbus" and len(parts) == 2:
                (package / parts[1]).symlink_to(tree / source)
        yield site
