"""A mission's states, apart from its plan's models, so the stores can name them without pydantic."""

from __future__ import annotations

from enum import Enum


class MissionState(str, Enum):
    PLANNING = "planning"
    FILED = "filed"
    APPROVED = "approved"
    IN_PROGRESS = "in_progress"
    INTERRUPTED = "interrupted"
    REVIEWING = "reviewing"
    CLOSED = "closed"
