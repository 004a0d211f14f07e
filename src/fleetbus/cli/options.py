"""Options more than one command takes: declared once, so each command's help and checks agree."""

from __future__ import annotations

from typing import Annotated

import typer

from fleetbus.cli.context import fail, no_password_in_argv, settings

#: A robot's ``--url`` (``fleetbus publish``, ``fleetbus ros bridge``): check it with
#: :func:`check_url_option`, resolve it with :func:`robot_url`.
RobotUrl = Annotated[
    str | None,
    typer.Option(
        "--url",
        help="the robot's AMQP URL without a password (a client certificate's; default: "
        "FLEETBUS_ROBOT_URL, else the one `users add` kept)",
    ),
]


def check_url_option(url: str | None) -> None:
    """Refuse a robot's ``--url`` that holds a password (every user of the machine sees it)."""
    no_password_in_argv(url, "--url", "in FLEETBUS_ROBOT_URL, or as `users add` kept it")


def robot_url(robot: str, url: str | None) -> str:
    """The robot's AMQP URL: ``url`` (its ``--url``), else FLEETBUS_ROBOT_URL, else the one
    `users add` kept; the command ends when there is none."""
    url = url or settings().robot_url
    if url:
        return url
    saved = settings().accounts_dir / f"{robot}.url"
    if saved.exists():
        return saved.read_text().strip()
    fail(f"no credentials for {robot!r}: use --url, FLEETBUS_ROBOT_URL or `fleetbus users add {robot}`")
