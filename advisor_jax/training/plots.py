"""The figures of a training run: learning curves (paper Fig. 8-10) and learner diagnostics.

Both draw one line per grid point (mean over its seeds) so that a sweep's settings can be
compared; ``save_png`` writes any matplotlib figure atomically.
"""

from __future__ import annotations

import io
import math
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import envs
from advisor_jax.fileio import atomic_write_bytes
from advisor_jax.stats import MIN_SEEDS_FOR_INTERVAL
from advisor_jax.training.reporting import group_agents, group_label, moving_average, seeds_text


def plot_learning_curves(
    path: Path, metrics, agents, grid, *, name: str, arena: str, advisor_data: bool = False
) -> None:
    """Fig. 8-style reward per step and success, moving average, mean ± std over seeds, of
    agent type ``name`` trained in ``arena`` (``advisor_data``: draw Eq. 11's maximum)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    n_total = metrics["outcome"].shape[1]
    window = max(1, min(150, n_total // 5))
    success = np.where(metrics["outcome"] > 0, metrics["outcome"] == envs.GOAL, np.nan)
    panels = (
        ("reward per step", metrics["reward_per_step"]),
        ("success rate", success.astype(np.float64)),
        ("actor firing rate", metrics["firing_rate"]),
    )
    fig, axes = plt.subplots(1, 3, figsize=(15, 4), constrained_layout=True)
    episodes = np.arange(1, n_total + 1)
    keep = ~metrics["diverged"]
    for key, members in group_agents(agents, grid).items():
        members = [m for m in members if keep[m]]
        if not members:
            continue
        label = group_label(key, grid, name)
        for ax, (_, values) in zip(axes, panels, strict=True):
            curves = moving_average(values[members].astype(np.float64), window)
            mean = np.nanmean(curves, axis=0) if np.isfinite(curves).any() else curves[0]
            (line,) = ax.plot(episodes, mean, label=f"{label} ({seeds_text(len(members))})")
            if len(members) >= MIN_SEEDS_FOR_INTERVAL:  # a spread of 2 seeds says little
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # episodes without data
                    std = np.nanstd(curves, axis=0)
                ax.fill_between(episodes, mean - std, mean + std, color=line.get_color(), alpha=0.2)
    if advisor_data:
        expected = np.nanmean(metrics["expected_max_firing_rate"][keep], axis=0)
        axes[2].plot(episodes, expected, "r--", lw=1, label="Eq. (11) expected maximum")
        axes[2].legend(fontsize=8)
    for ax, (title, _) in zip(axes, panels, strict=True):
        ax.set_xlabel("episode")
        ax.set_ylabel(title)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_title(f"{title} (moving average, w={window})")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(
        f"{name} in '{arena}': mean over seeds; shaded: ± std over seeds (from "
        f"{MIN_SEEDS_FOR_INTERVAL} seeds on)"
    )
    save_png(fig, path)


DIAGNOSTICS = (
    ("loss/critic", "critic loss"),
    ("q/mean", "Q(s, a) on replayed batches"),
    ("loss/actor", "actor loss"),
    ("advisor/replaced", "AfP: replaced fraction of the batch"),
    ("diag/grad_q_rms", "rms ‖∇_a Q‖"),
    ("diag/step", "mean ‖Eq. 2 step‖"),
    ("diag/advisor_gap", "mean ‖a_adv − π(s)‖ where replaced"),
    ("diag/q_gain", "mean Q(s, a_adv) − Q(s, â)"),
    ("diag/saturated", "saturated output heads (fraction)"),
)


def plot_diagnostics(
    path: Path, series: Mapping[str, np.ndarray], agents, grid, *, name: str, arena: str
) -> None:
    """Learner diagnostics over training: one line per grid point (mean over its seeds, thin
    lines for each seed), so a sweep's settings can be compared where they diverge."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(k, title) for k, title in DIAGNOSTICS if k in series]
    if not panels or series["step"].size == 0:
        return
    cols = 3
    rows = math.ceil(len(panels) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(15, 3.4 * rows), constrained_layout=True)
    axes = np.atleast_1d(axes).ravel()
    steps = series["step"]
    for key, members in group_agents(agents, grid).items():
        label = group_label(key, grid, name)
        for ax, (metric, _) in zip(axes, panels, strict=False):
            values = series[metric][members]
            if not np.isfinite(values).any():
                continue
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # chunks with no value yet
                mean = np.nanmean(values, axis=0)
            (line,) = ax.plot(steps, mean, label=f"{label} ({seeds_text(len(members))})")
            for row in values if len(members) > 1 else ():
                ax.plot(steps, row, color=line.get_color(), lw=0.5, alpha=0.35)
    for ax, (_, title) in zip(axes, panels, strict=False):
        ax.set_title(title)
        ax.set_xlabel("environment step")
        ax.set_ylabel(title)
        ax.grid(alpha=0.3)
    for ax in axes[len(panels) :]:
        ax.axis("off")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{name} in '{arena}': learner diagnostics per chunk")
    save_png(fig, path)


def save_png(fig, path: str | Path, dpi: int = 110) -> Path:
    """Writes a matplotlib figure as PNG atomically and closes it: 256 colours
    (``palette_png``), a third of the bytes of matplotlib's RGBA file."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    plt.close(fig)
    return atomic_write_bytes(path, palette_png(buf.getvalue()))


def palette_png(png: bytes) -> bytes:
    """A PNG re-encoded with an adaptive palette of 256 colours (no dithering), or the
    original where that is not smaller. Plots have few distinct colours; what the
    palette merges are antialiasing shades."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    palette = image.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    buf = io.BytesIO()
    palette.save(buf, format="PNG", optimize=True)
    return buf.getvalue() if len(buf.getvalue()) < len(png) else png
