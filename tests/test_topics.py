"""Topic patterns match as RabbitMQ's topic exchange does (the cases of its tutorial and edge cases)."""

from __future__ import annotations

import pytest

from fleetbus.publishers.tls import blocking_connection
from fleetbus.schemas.topics import topic_matches
from tests.support import Bus


@pytest.mark.parametrize(
    ("pattern", "key", "expected"),
    [
        ("#", "", True),
        ("#", "explorer1.hazard", True),
        ("*", "explorer1", True),
        ("*", "explorer1.hazard", False),
        ("*.hazard", "explorer1.hazard", True),
        ("*.hazard", "explorer1.tf.extra", False),
        ("explorer1.#", "explorer1", True),
        ("explorer1.#", "explorer1.tf.child", True),
        ("explorer1.#", "explorer10.tf", False),
        ("#.hazard", "hazard", True),
        ("#.hazard", "a.b.hazard", True),
        ("#.hazard", "a.b.hazards", False),
        ("a.#.z", "a.z", True),
        ("a.#.z", "a.b.c.z", True),
        ("a.#.z", "a.b.c", False),
        ("a.*.#", "a", False),
        ("a.*.#", "a.b", True),
        ("notify.hazard", "notify.hazard", True),
        ("notify.hazard", "notify.map", False),
        ("#.#", "x.y", True),
    ],
)
def test_topic_patterns(pattern: str, key: str, expected: bool) -> None:
    assert topic_matches(pattern, key) is expected


#: Words a pattern or key is made of: literals, wildcards and the empty word (``a..b``, ``.a``, ``a.``).
PATTERN_WORDS = ("x", "y", "*", "#", "")
KEY_WORDS = ("x", "y", "")


def _joined(words: tuple[str, ...], longest: int) -> list[str]:
    found = {""}
    layer: list[tuple[str, ...]] = [()]
    for _ in range(longest):
        layer = [(*seq, word) for seq in layer for word in words]
        found.update(".".join(seq) for seq in layer)
    return sorted(found)


def test_the_matcher_routes_as_rabbitmq_does_on_every_pattern_and_key(bus: Bus) -> None:
    """Thousands of (pattern, key) pairs: a queue per pattern bound to a real topic exchange, each key
    published once (confirmed), and what each queue received compared with :func:`topic_matches`."""
    patterns = _joined(PATTERN_WORDS, 3)
    keys = _joined(KEY_WORDS, 3)
    assert len(patterns) * len(keys) > 5000
    connection = blocking_connection(bus.admin_url)
    try:
        channel = connection.channel()
        channel.exchange_declare("topics.check", "topic", auto_delete=True)
        queues = {}
        for n, pattern in enumerate(patterns):
            queue = f"topics.check.{n}"
            channel.queue_declare(queue, exclusive=True)
            channel.queue_bind(queue, "topics.check", routing_key=pattern)
            queues[pattern] = queue
        channel.confirm_delivery()
        for key in keys:
            channel.basic_publish("topics.check", key, key.encode())
        routed = {}
        for pattern, queue in queues.items():
            received = set()
            while True:
                method, _, body = channel.basic_get(queue, auto_ack=True)
                if method is None:
                    break
                received.add(body.decode())
            routed[pattern] = received
    finally:
        connection.close()
    wrong = [
        (pattern, key, key in routed[pattern])
        for pattern in patterns
        for key in keys
        if topic_matches(pattern, key) != (key in routed[pattern])
    ]
    assert wrong == [], f"{len(wrong)} pairs routed otherwise (pattern, key, RabbitMQ's answer): {wrong[:20]}"


@pytest.mark.parametrize(("pattern", "key"), [("x.#.#", "x"), ("a..b", "a..b"), ("#", ""), ("a.", "a.")])
def test_the_tail_uses_the_one_matcher(pattern: str, key: str) -> None:
    import fleetbus.broker.tail

    assert fleetbus.broker.tail.topic_matches is topic_matches
    assert topic_matches(pattern, key)
