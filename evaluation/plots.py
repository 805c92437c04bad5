"""Matplotlib figures of the evaluation reports (written as PNG, no display needed).

Every figure is rendered in memory and written atomically (`data.atomic_write`):
a failed write leaves the previous file, never half a PNG.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.atomic_write import output_dir, write_bytes_atomic

Array = NDArray[np.float64]


def save_figure(fig: plt.Figure, path: Path, dpi: int = 120) -> Path:
    """Lay out `fig`, write it to `path` (format from the suffix, PNG by default) and close it.

    The folder of `path` is made if needed.

    Raises:
        DataError: the folder cannot be made or the file cannot be written.
    """
    try:
        output_dir(path.parent)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format=path.suffix.lstrip(".").lower() or "png", dpi=dpi)
        write_bytes_atomic(path, buf.getvalue())
    finally:
        plt.close(fig)
    return path


def save_image(path: Path, image: ArrayLike, cmap: str = "gray") -> Path:
    """Write the 2-D array `image` as a PNG (`matplotlib.pyplot.imsave`, colour map `cmap`).

    Raises:
        DataError: the folder cannot be made or the file cannot be written.
    """
    output_dir(path.parent)
    buf = io.BytesIO()
    plt.imsave(buf, image, cmap=cmap, format="png")
    return write_bytes_atomic(path, buf.getvalue())


def plot_trajectories(
    path: Path,
    trajectories: Mapping[str, Array],
    title: str = "",
    loops: Sequence[tuple[Array, Array]] | None = None,
) -> Path:
    """Planar trajectories ``name -> (N, 2+) xy`` [m] on equal axes, optional loop lines."""
    fig, ax = plt.subplots(figsize=(7, 6))
    for name, xy in trajectories.items():
        ax.plot(xy[:, 0], xy[:, 1], lw=1.0, label=name)
    for a, b in loops or []:
        ax.plot([a[0], b[0]], [a[1], b[1]], color="tab:red", lw=0.5, alpha=0.6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def plot_error_series(path: Path, stamps: Array, errors: Array, ylabel: str, title: str) -> Path:
    """An error per pose over time."""
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(stamps - stamps[0], errors, lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def plot_histogram(path: Path, values: Array, xlabel: str, title: str, bins: int = 50) -> Path:
    """Histogram of per-relation (or per-pose) errors."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.hist(values, bins=bins, color="tab:blue", alpha=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("count")
    ax.set_title(title)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def plot_curves(
    path: Path,
    curves: Mapping[str, tuple[Array, Array]],
    xlabel: str,
    ylabel: str,
    title: str,
    diagonal: bool = False,
) -> Path:
    """Several ``name -> (x, y)`` curves (ROC, precision-recall) on one unit square."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    for name, (x, y) in curves.items():
        ax.plot(x, y, lw=1.2, label=name)
    if diagonal:
        ax.plot([0, 1], [0, 1], color="grey", lw=0.6, ls="--")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def plot_robustness(path: Path, rows: Sequence[Mapping[str, float | str]], title: str) -> Path:
    """ATE against the clean optimum versus the outlier ratio, one line per kernel."""
    fig, ax = plt.subplots(figsize=(6, 4))
    kernels = sorted({str(r["kernel"]) for r in rows})
    for k in kernels:
        mine = [r for r in rows if r["kernel"] == k]
        pts = sorted((float(r["outlier_ratio"]), float(r["ate_vs_clean_m"])) for r in mine)
        x, y = zip(*pts, strict=True)
        ax.plot(100 * np.array(x), np.maximum(np.array(y), 1e-6), marker="o", label=k)
    ax.set_yscale("log")
    ax.axhline(0.05, color="grey", ls="--", lw=0.6)
    ax.set_xlabel("false loop closures [% of loop edges]")
    ax.set_ylabel("ATE vs outlier-free optimum [m]")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", lw=0.3)
    return save_figure(fig, path)
