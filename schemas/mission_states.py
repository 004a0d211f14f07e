"""A mission's states, apart from its plan's models, so the stores can name them without pydantic."""

from __future__ import annotations

from enum import Enum


class MissionState(str, Enum):
    """Declared in life-cycle order: the order every list of states and every sort by state uses
    (:attr:`rank`)."""

    PLANNING = "planning"
    FILED = "filed"
    APPROVED = "approved"
    IN_PROGRESS = "in_progress"
    INTERRUPTED = "interrupted"
    REVIEWING = "reviewing"
    CLOSED = "closed"

    @property
    def rank(self) -> int:
        """The state's place in the life cycle, from 0 (planning) to 6 (closed)."""
        return list(MissionState).index(self)
