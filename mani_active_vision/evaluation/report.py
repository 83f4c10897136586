"""Reports: markdown tables of episode summaries, mean ± spread over runs, and learning-curve plots."""

from __future__ import annotations

import functools
import math

import matplotlib

matplotlib.use("Agg")  # files only: no display on the machines this runs on
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def markdown_table(rows: dict[str, dict]) -> str:
    """rows: name -> `metrics.summarize` output; one row each, mean ± std. Focus held is the mean over the
    successful episodes ("–" when none succeeded; `metrics`)."""
    header = (
        "| policy | episodes | success | success at end | focus held | steps to see | steps to success | SPL "
        "| final target fraction | return |"
    )
    lines = [header, "|" + "---|" * 10]
    for name, s in rows.items():
        cell = functools.partial(_cell, s)
        spl = "–" if math.isnan(s["spl"]) else f"{s['spl']:.2f}"  # no reference run: no SPL
        lines.append(
            f"| {name} | {s['episodes']} | {s['success']:.2f} | {s['success_final']:.2f} | {cell('focus_held')} | "
            f"{cell('steps_to_see', '{:.1f}')} | {cell('steps_to_success', '{:.1f}')} | {spl} | "
            f"{cell('final_target_fraction', '{:.3f}')} | {cell('return')} |"
        )
    return "\n".join(lines)


def _cell(summary: dict, key: str, fmt: str = "{:.2f}") -> str:
    """ "mean ± std" of one metric of a summary, "–" when it does not exist."""
    if math.isnan(summary[key]):
        return "–"
    return f"{fmt.format(summary[key])} ± {fmt.format(summary[key + '_std'])}"


def spread(values, digits: int = 2) -> str:
    """ "mean ± std" of values (None and NaN left out), "–" when there are none."""
    values = np.asarray([np.nan if v is None else v for v in values], dtype=float)
    if np.isnan(values).all():
        return "–"
    return f"{np.nanmean(values):.{digits}f} ± {np.nanstd(values):.{digits}f}"


def moving_average(values, window: int) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    kernel = np.ones(min(window, len(values)))
    return np.convolve(values, kernel, "valid") / len(kernel)


def plot_curves(
    curves: dict[str, list], path: str, ylabel: str, window: int = 10, title: str = "", xlabel: str = "training episode"
):
    """Learning curves: label -> per-seed lists of per-episode values (or of other steps: `xlabel`); mean ± std
    over seeds of the moving average (window values; 1: none) of each."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, runs in curves.items():
        smooth = np.stack([moving_average(r, window) for r in runs])
        mean, std = smooth.mean(0), smooth.std(0)
        x = np.arange(len(mean)) + len(runs[0]) - len(mean) + 1
        ax.plot(x, mean, label=f"{label} ({len(runs)} seed{'s' if len(runs) > 1 else ''})")
        ax.fill_between(x, mean - std, mean + std, alpha=0.25)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{ylabel} ({window}-{xlabel.split()[-1]} moving average)" if window > 1 else ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
