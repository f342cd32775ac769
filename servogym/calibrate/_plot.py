"""The calibration plot: measured vs replayed position, following error and motor command."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def calibration_figure(trace: Any, cal: Any, title: str = ""):
    """A matplotlib Figure (no pyplot state): three panels sharing the time axis.

    1. position: commanded, measured, closed-loop replay, open-loop replay (counts);
    2. following error (commanded - actual): measured and closed-loop replay, and the
       replay's position error (replay - measured) (counts);
    3. motor command: measured and closed-loop replay (counts).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 8.0))
    ax = fig.subplots(3, 1, sharex=True)
    t = np.asarray(trace.time_s) - float(trace.time_s[0])
    ax[0].plot(t, trace.commanded, color="0.6", lw=1.0, label="commanded")
    ax[0].plot(t, trace.actual, color="k", lw=1.2, label="measured")
    ax[0].plot(t, cal.replay.actual, "--", color="tab:red", lw=1.0, label="closed-loop replay")
    ax[0].plot(t, cal.open_replay.actual, ":", color="tab:blue", lw=1.0,
               label="open-loop replay (re-anchored)")  # fmt: skip
    ax[0].set_ylabel("position (counts)")
    ax[0].legend(loc="best", fontsize="small")
    ax[1].plot(t, trace.commanded - trace.actual, color="k", lw=1.0, label="measured")
    ax[1].plot(t, trace.commanded - cal.replay.actual, "--", color="tab:red", lw=1.0,
               label="closed-loop replay")  # fmt: skip
    ax[1].plot(t, cal.replay.actual - trace.actual, color="tab:orange", lw=0.8,
               label=f"replay - measured (RMS {cal.rms_error_counts:.3g})")  # fmt: skip
    ax[1].set_ylabel("following error (counts)")
    ax[1].legend(loc="best", fontsize="small")
    ax[2].plot(t, trace.command, color="k", lw=1.0, label="measured")
    ax[2].plot(t, cal.replay.command, "--", color="tab:red", lw=1.0, label="closed-loop replay")
    ax[2].set_ylabel("motor command (counts)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title, fontsize="medium")
    fig.tight_layout()
    return fig


def plot_calibration(trace: Any, cal: Any, path: str | Path, title: str = "") -> Path:
    """Write :func:`calibration_figure` as a PNG (atomically)."""
    import io

    from servogym._files import write_atomic

    buf = io.BytesIO()
    calibration_figure(trace, cal, title).savefig(buf, format="png", dpi=110)
    return write_atomic(path, buf.getvalue())
