"""Topic patterns match as RabbitMQ's topic exchange does (the cases of its tutorial and edge cases)."""

from __future__ import annotations

import pytest

from broker.topics import topic_matches


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
