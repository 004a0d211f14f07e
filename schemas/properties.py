"""The AMQP properties of an event message, besides its body: what a robot in any language sets,
and the checks the workers make of them. The AsyncAPI document publishes the same rules.

- ``user_id``: the robot's login. The broker refuses any other name (it closes the channel);
  a message without one is refused by the workers (``no-user-id``).
- ``content_type``: ``application/json`` (a ``charset=utf-8`` parameter may follow); anything
  else, or none, is refused (``content-type``).
- ``delivery_mode``: 2, persistent, so that the broker keeps it on disk until the workers stored
  it; a transient message is refused (``not-persistent``) rather than left to be lost at the next
  broker restart.
- ``message_id``: the event's ``message_id`` (any id of the robot's own when the body has none);
  fleetbus names the message by it in logs, dead letters and ``fleetbus trace``. Not checked:
  which event a message is comes from its body (:mod:`fleetbus.schemas.envelope`).
"""

from __future__ import annotations

from email.message import Message

EVENT_CONTENT_TYPE = "application/json"
PERSISTENT = 2


def content_type_problem(content_type: str | None, what: str = "events") -> str | None:
    """Why ``content_type`` is not that of ``what`` (events, service requests: both JSON), or
    None when it is."""
    if not content_type:
        return f"the message has no content_type property; {what} are {EVENT_CONTENT_TYPE}"
    parsed = Message()  # the standard library's MIME header parser
    parsed["content-type"] = content_type
    charset = parsed.get_param("charset", "utf-8")
    if parsed.get_content_type() != EVENT_CONTENT_TYPE or str(charset).lower() != "utf-8":
        return f"content_type is {content_type!r}; {what} are {EVENT_CONTENT_TYPE} (UTF-8)"
    return None


def delivery_mode_problem(delivery_mode: int | None) -> str | None:
    """Why ``delivery_mode`` is not an event's, or None when it is."""
    if delivery_mode != PERSISTENT:
        shown = "not set" if delivery_mode is None else f"{int(delivery_mode)} (transient)"
        return (
            f"delivery_mode is {shown}; events are persistent (delivery_mode {PERSISTENT}), or a broker "
            "restart before the workers stored them loses them"
        )
    return None
