"""Response plots: commanded vs actual position, error and motor command over time."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def _figure(n_rows: int, width: float = 9.0, height: float = 7.0):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height))
    axes = fig.subplots(n_rows, 1, sharex=True)
    return fig, axes


def _joined(evaluation: Any) -> dict[str, np.ndarray]:
    """Concatenate the traces of an Evaluation's moves (or take one EpisodeResult's)."""
    results = getattr(evaluation, "results", None) or [evaluation]
    parts = [r.traces for r in results if r.traces is not None]
    if not parts:
        raise ValueError("no traces to plot: evaluate or run with traces=True")
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "cmd", "act", "err", "u")}
    t0 = 0.0
    for tr in parts:
        dt = tr.time_s[1] - tr.time_s[0] if len(tr.time_s) > 1 else 0.0
        out["t"].append(tr.time_s + t0)
        t0 += tr.time_s[-1] + dt
        out["cmd"].append(tr.commanded)
        out["act"].append(tr.actual)
        out["err"].append(tr.error)
        out["u"].append(tr.command)
    return {k: np.concatenate(v) for k, v in out.items()}


def response_figure(runs: Sequence[tuple[str, Any]], title: str = ""):
    """A matplotlib Figure (no pyplot state) of labelled Evaluations or EpisodeResults."""
    fig, (ax_pos, ax_err, ax_cmd) = _figure(3)
    for i, (label, run) in enumerate(runs):
        d = _joined(run)
        if i == 0:
            ax_pos.plot(d["t"], d["cmd"], "k--", lw=1.0, label="commanded")
        ax_pos.plot(d["t"], d["act"], lw=1.2, label=f"actual ({label})")
        ax_err.plot(d["t"], d["err"], lw=1.0, label=label)
        ax_cmd.plot(d["t"], d["u"], lw=0.8, label=label)
    ax_pos.set_ylabel("position (counts)")
    ax_err.set_ylabel("error (counts)")
    ax_cmd.set_ylabel("motor command\n(counts, 32768 = 100 %)")
    ax_cmd.set_xlabel("time (s)")
    for ax in (ax_pos, ax_err, ax_cmd):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_response(runs: Sequence[tuple[str, Any]], path: str | Path, title: str = "") -> Path:
    """Write a response plot (PNG) of one or more labelled runs; returns the path."""
    fig = response_figure(runs, title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def response_rgb(runs: Sequence[tuple[str, Any]], title: str = "") -> np.ndarray:
    """The response plot as an RGB array (H, W, 3) uint8, for ``render_mode="rgb_array"``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = response_figure(runs, title)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
