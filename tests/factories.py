"""Event bodies for tests, as a robot would build them."""

from __future__ import annotations

import base64
from datetime import datetime, timedelta, timezone
from typing import Any

TABLE1_TIME = "2021-06-01T18:25:26.564500+00:00"


def hazard(i: int = 0, description: str = "Fire") -> dict[str, Any]:
    detected = datetime.fromisoformat(TABLE1_TIME) + timedelta(seconds=i)
    return {
        "pose": {"x": 2.66 + i, "y": 1.22, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "frame_id": "map",
        "description": description,
        "detected_at": detected.isoformat(),
    }


def status(battery: float = 80.0) -> dict[str, Any]:
    return {"battery_percent": battery, "pose": {"x": 0.0, "y": 0.0}, "processing_rate_hz": 10.0}


def small_map(width: int = 64, height: int = 48) -> dict[str, Any]:
    header = f"P5\n{width} {height}\n255\n".encode()
    pixels = bytes((x * 7 + y) % 256 for y in range(height) for x in range(width))
    return {
        "pgm": base64.b64encode(header + pixels).decode(),
        "metadata": {
            "image": "map.pgm",
            "resolution": 0.11,
            "origin": [2.1, 3.5, 0.0],
            "occupied_thresh": 0.65,
            "free_thresh": 0.196,
            "negate": 0,
        },
        "created_at": datetime(2021, 6, 1, 18, 25, 26, 564500, tzinfo=timezone.utc).isoformat(),
    }
