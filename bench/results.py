"""What every benchmark does with its runs: medians, and a JSON file per run in bench/results/."""

from __future__ import annotations

import json
import statistics
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any


def medians(runs: Sequence[dict[str, float]]) -> dict[str, float]:
    return {key: statistics.median(run[key] for run in runs) for key in runs[0]}


def spread(runs: Sequence[dict[str, float]], key: str, digits: int = 0) -> str:
    values = [run[key] for run in runs]
    return f"{min(values):,.{digits}f}-{max(values):,.{digits}f}"


def save(out: Path, name: str, data: dict[str, Any]) -> Path:
    """``out/<name>-<UTC time>.json``."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}-{datetime.now(timezone.utc):%Y%m%dT%H%M%S}.json"
    path.write_text(json.dumps(data, indent=2))
    return path


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0-100), interpolated between the nearest ranks."""
    ordered = sorted(values)
    if len(ordered) == 1:
        return ordered[0]
    rank = (len(ordered) - 1) * q / 100
    low = int(rank)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (rank - low)
