"""A login the broker refused, told apart from an outage and said in words.

pika raises ``ProbableAuthenticationError`` when the broker refused the robot's name and
password (or certificate), ``ProbableAccessDeniedError`` when it let the robot in but not into
its virtual host. Both are ``AMQPConnectionError``s, like a broker that is away: without this a
rotated password looked like an outage that never ended. Base install: pika only.
"""

from __future__ import annotations

import pika.exceptions

LOGIN_REFUSED: tuple[type[Exception], ...] = (
    pika.exceptions.ProbableAuthenticationError,
    pika.exceptions.ProbableAccessDeniedError,
)


def login_refusal(error: BaseException, robot_id: str) -> str | None:
    """What ``error``, raised while ``robot_id`` connected, says of its login; None when it is no
    refusal. Names the robot, never its password (pika's message does not carry it)."""
    if isinstance(error, pika.exceptions.ProbableAccessDeniedError):
        return (
            f"the broker refused robot {robot_id} access to its virtual host (its permissions "
            f"were removed?): {error!r}"
        )
    if isinstance(error, pika.exceptions.ProbableAuthenticationError):
        return (
            f"the broker refused robot {robot_id}'s credentials (a wrong or changed password, or "
            f"the account removed): {error!r}"
        )
    return None
