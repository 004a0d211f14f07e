"""Pictures for people: PNG plots with matplotlib (Agg, so no display is needed)."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt

if TYPE_CHECKING:
    from fleetbus.api.services.recording import OutcomeStats


def plot_growth(
    times: Sequence[datetime],
    megabytes_per_minute: Sequence[float],
    inserts_per_minute: Sequence[float],
    path: Path,
) -> Path:
    """The reference's Fig. 7: database growth (MB/min) above, inserts per minute below."""
    figure, (growth, inserts) = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5), constrained_layout=True)
    growth.plot(times, megabytes_per_minute, color="tab:blue", drawstyle="steps-post")
    growth.set_ylabel("MB per minute")
    growth.set_title("recording: database growth")
    inserts.plot(times, inserts_per_minute, color="tab:orange", drawstyle="steps-post")
    inserts.set_ylabel("inserts per minute")
    inserts.set_xlabel("time (UTC)")
    for axes in (growth, inserts):
        axes.grid(alpha=0.3)
        axes.set_ylim(bottom=0)
    figure.autofmt_xdate()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def plot_evaluation(stats: Sequence[OutcomeStats], path: Path, title: str) -> Path:
    """Per behaviour: success rate (bars) and mean duration with its standard deviation."""
    names = [s.name for s in stats]
    figure, (rates, durations) = plt.subplots(
        1, 2, figsize=(10, 0.5 * len(names) + 2.5), constrained_layout=True
    )
    rates.barh(names, [100 * s.success_rate for s in stats], color="tab:green")
    rates.set_xlim(0, 100)
    rates.set_xlabel("success rate (%)")
    for y, s in enumerate(stats):
        rates.annotate(f"{s.successes}/{s.runs}", (1, y), va="center", fontsize=8)
    durations.barh(
        names, [s.mean_duration for s in stats], xerr=[s.std_duration for s in stats], color="tab:blue"
    )
    durations.set_xlabel("duration (s): mean ± standard deviation")
    durations.tick_params(labelleft=False)
    for axes in (rates, durations):
        axes.invert_yaxis()
        axes.grid(axis="x", alpha=0.3)
    figure.suptitle(title)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
