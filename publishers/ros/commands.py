"""The commands of the operator who mounted the robot, read from its commands queue for ROS.

A command is a message an operator sends to ``<operator>.commands`` with the key
``<robot>.<command>``; mounting binds it to the robot's ``<robot>.commands`` queue. Each one
becomes a line for the ROS side: ``/fleetbus/command`` (``std_msgs/String``, the command as JSON)
and, for a ``goal`` whose body holds ``x`` and ``y``, ``/fleetbus/goal``
(``geometry_msgs/PoseStamped``, as RViz's 2D Nav Goal sends one).
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from typing import Any

import pika
import pika.exceptions

from fleetbus.publishers.errors import CONNECTION_FAILED
from fleetbus.publishers.tls import pika_parameters
from fleetbus.schemas.routing import commands_queue

log = logging.getLogger("fleetbus.ros")


def command_messages(
    robot: str, routing_key: str, operator: str | None, body: bytes, prefix: str
) -> list[dict[str, Any]]:
    """The ROS messages of one command."""
    name = routing_key[len(robot) + 1 :] if routing_key.startswith(f"{robot}.") else routing_key
    try:
        content: Any = json.loads(body)
    except ValueError:
        content = body.decode("utf-8", "replace")
    command = {"command": name, "operator": operator, "body": content}
    messages = [
        {
            "kind": "publish",
            "topic": f"{prefix}/command",
            "type": "std_msgs/String",
            "fields": {"data": json.dumps(command)},
        }
    ]
    if name == "goal" and isinstance(content, dict) and {"x", "y"} <= set(content):
        try:
            x, y = float(content["x"]), float(content["y"])
        except (TypeError, ValueError):  # not a place: it goes as the command's text alone
            log.warning("commands: a goal from %s with no place in it (x, y): %r", operator, content)
            return messages
        orientation = content.get("orientation") or {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
        messages.append(
            {
                "kind": "publish",
                "topic": f"{prefix}/goal",
                "type": "geometry_msgs/PoseStamped",
                "fields": {
                    "header": {"frame_id": str(content.get("frame_id", "map"))},
                    "pose": {
                        "position": {"x": x, "y": y, "z": 0.0},
                        "orientation": orientation,
                    },
                },
            }
        )
    return messages


def follow_commands(
    amqp_url: str,
    robot: str,
    prefix: str,
    send: Callable[[list[dict[str, Any]]], None],
    stop: threading.Event,
) -> None:
    """Hand each command to ``send`` (then ack it) until ``stop``; reconnect when the broker goes."""
    parameters = pika_parameters(amqp_url)
    while not stop.is_set():
        try:
            connection = pika.BlockingConnection(parameters)
        except (pika.exceptions.AMQPError, *CONNECTION_FAILED) as error:
            log.warning("commands: cannot reach the broker (%s); trying again", error)
            stop.wait(2.0)  # the broker is away: try again later
            continue
        try:
            channel = connection.channel()
            channel.basic_qos(prefetch_count=16)
            for method, properties, body in channel.consume(commands_queue(robot), inactivity_timeout=0.5):
                if stop.is_set():
                    break
                if method is None:
                    continue
                send(command_messages(robot, method.routing_key, properties.user_id, body, prefix))
                channel.basic_ack(method.delivery_tag)
        except pika.exceptions.AMQPError as error:
            log.warning("commands: %s; reconnecting", error)
        finally:
            if connection.is_open:
                try:
                    connection.close()
                except pika.exceptions.AMQPError:
                    pass
