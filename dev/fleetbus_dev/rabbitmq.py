"""The RabbitMQ installation a private node runs from (``FLEETBUS_RABBITMQ_ROOT``).

Either the host's Debian package (root ``/``), or Debian 13's package in a root of its own that
``scripts/rabbitmq-root`` builds with debootstrap on an older Debian (Debian 13's Erlang needs a
newer C library than Debian 12 has). A node in a root runs with ``chroot``, sharing the host's
network and processes (its beam's PID is an ordinary host PID: tests kill it), in a mount
namespace of its own (``unshare --mount``) where the host's ``/proc``, ``/dev``, ``/sys`` and the
node's folders are bind-mounted at the same paths: the node reads and writes exactly the files it
would on the host. Those mounts exist in that namespace only, so they need no clean-up: they go
with the last process in it (the node, or its epmd).

:meth:`Installation.command` is the one place that turns a RabbitMQ tool and its arguments into
a command line; :class:`~fleetbus_dev.local_node.LocalNode` runs the server, ``rabbitmqctl`` and
``rabbitmq-plugins`` through it.
"""

from __future__ import annotations

import os
import re
import shlex
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

HOST = Path("/")
#: Where ``scripts/rabbitmq-root`` builds the Debian 13 root unless ``FLEETBUS_RABBITMQ_ROOT`` names one.
DEFAULT_ROOT = Path("/var/cache/fleetbus/rabbitmq-trixie")
#: Written last by ``scripts/rabbitmq-root``: a root without it is not (completely) built.
ROOT_MARKER = ".fleetbus-rabbitmq-root"
#: The RabbitMQ tools, inside the installation's root (Debian's layout, both releases).
BIN = Path("/usr/lib/rabbitmq/bin")
LIB = Path("/usr/lib/rabbitmq/lib")
#: The release the test suite runs on (Debian 13's), which compose.yaml pins too.
TESTED_RELEASE = "4.0.5"
#: The older release CI runs the tests of what differs between releases on (Debian 12's).
COMPATIBLE_RELEASE = "3.10.8"
#: Top-level folders of the root that belong to its system: a node folder under one of them is
#: mounted itself, never the host's whole folder over the root's.
SYSTEM_FOLDERS = frozenset("bin boot dev etc lib lib32 lib64 opt proc run sbin srv sys usr var".split())
SETUP_HINT = "run scripts/setup (it installs RabbitMQ: Debian 13's, or a Debian 13 root on an older Debian)"


def version_key(version: str) -> tuple[int, ...]:
    """``"4.0.5"`` as ``(4, 0, 5)``, for comparisons."""
    return tuple(int(part) for part in re.findall(r"\d+", version)[:3])


@dataclass(frozen=True)
class Installation:
    """RabbitMQ installed under ``root`` (``/``: the host's own package)."""

    root: Path

    @property
    def chrooted(self) -> bool:
        return self.root != HOST

    def path(self, inside: Path) -> Path:
        """``inside`` (an absolute path in the root) as the host sees it."""
        return self.root / inside.relative_to("/")

    def version(self) -> str | None:
        """The installed release, from its folder (``rabbitmq_server-4.0.5``); None when missing."""
        found = sorted(self.path(LIB).glob("rabbitmq_server-*"), key=lambda p: version_key(p.name))
        return found[-1].name.removeprefix("rabbitmq_server-") if found else None

    def exists(self) -> bool:
        return (self.path(BIN) / "rabbitmq-server").exists() and self.version() is not None

    def describe(self) -> str:
        where = f"the root {self.root}" if self.chrooted else "the host's package"
        return f"RabbitMQ {self.version() or '(not installed)'} ({where})"

    def require(self) -> None:
        if not self.exists():
            if self.chrooted:
                raise InstallationError(
                    f"RabbitMQ is not installed in the root {self.root} "
                    f"(FLEETBUS_RABBITMQ_ROOT): {SETUP_HINT}, or `bash scripts/rabbitmq-root --rebuild`"
                )
            raise InstallationError(f"RabbitMQ is not installed ({self.path(BIN)} is missing): {SETUP_HINT}")

    def env(self) -> dict[str, str]:
        """What the tools need besides the node's own variables: the plugins' folder, which 4.x's
        ``rabbitmq-plugins`` does not find by itself when called by its path (only Debian's
        ``/usr/sbin`` wrapper sets it; 3.10 needs no such thing)."""
        version = self.version()
        if version is None:
            return {}
        return {"RABBITMQ_PLUGINS_DIR": str(LIB / f"rabbitmq_server-{version}" / "plugins")}

    def command(self, tool: str, args: Sequence[str], shared: Iterable[Path], cwd: Path) -> list[str]:
        """The command line that runs ``tool ARGS`` (``rabbitmq-server``, ``rabbitmqctl``...) in
        ``cwd``; in a root, with the folders ``shared`` visible at their own paths."""
        argv = [str(BIN / tool), *args]
        if not self.chrooted:
            return argv
        quote = shlex.quote
        root = self.root
        lines = ["set -e"]
        for folder in ("proc", "dev", "sys"):
            lines.append(f"mount --rbind /{folder} {quote(str(root / folder))}")
        for folder in mount_points(shared):
            target = quote(str(self.path(folder)))
            lines.append(f"mkdir -p {target}")
            lines.append(f"mount --rbind {quote(str(folder))} {target}")
        # chroot starts in the root's /: the inner shell moves to the node's folder, then becomes the tool
        inner = 'cd "$1" && shift && exec "$@"'
        lines.append(
            f"exec chroot {quote(str(root))} /bin/sh -c {quote(inner)} sh {quote(str(cwd))} "
            + " ".join(quote(part) for part in argv)
        )
        return ["unshare", "--mount", "--propagation", "private", "--", "/bin/sh", "-c", "\n".join(lines)]


class InstallationError(RuntimeError):
    """RabbitMQ is missing, or is not the release a node's database needs; the message says why."""


def mount_points(folders: Iterable[Path]) -> list[Path]:
    """The host folders to mount in a root so that every one of ``folders`` is there: each one's
    top-level folder (``/tmp``, ``/work``, ``/home``), or the folder itself under a system folder
    of the root (``/var/lib/fleetbus``), without the ones another covers."""
    chosen: set[Path] = set()
    for folder in folders:
        folder = Path(os.path.abspath(folder))
        if len(folder.parts) < 2:
            continue
        top = Path("/", folder.parts[1])
        chosen.add(folder if folder.parts[1] in SYSTEM_FOLDERS else top)
    return sorted(p for p in chosen if not any(other != p and other in p.parents for other in chosen))


def default_installation() -> Installation:
    """Unless ``FLEETBUS_RABBITMQ_ROOT`` says otherwise: the host's package when it is 4.x or newer
    (Debian 13), else the Debian 13 root ``scripts/setup`` built, else the host's package."""
    host = Installation(HOST)
    version = host.version()
    if version is not None and version_key(version) >= (4,):
        return host
    built = Installation(DEFAULT_ROOT)
    if (DEFAULT_ROOT / ROOT_MARKER).exists() and built.exists():
        return built
    return host
