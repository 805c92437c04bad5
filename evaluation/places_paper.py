"""The place-recognition paper's published figures (Tables I-III), for comparison.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques
for place recognition" (``papers/shape-matching-place-recognition.txt``), Section III.B.
Columns are the paper's data sets (`PAPER_COLUMNS`); rows its eight matchers, keyed
by our matcher names (`PAPER_ROW_NAMES` gives the paper's spelling).
"""

from __future__ import annotations

PAPER_COLUMNS: tuple[str, ...] = ("box", "surface", "mpeg7", "robot")
COLUMN_TITLES = {"box": "Box", "surface": "Surface", "mpeg7": "MPEG-7", "robot": "Robot"}
PAPER_ROW_NAMES = {
    "fft": "Fft", "integral": "Integral", "ring": "Ring", "shape-context": "Shapecontext",
    "scanline": "Scanline", "mrm": "MRM", "tangent": "Tangent", "flirt": "Flirt",
}

PAPER_BULLSEYE: dict[str, tuple[float, float, float, float]] = {
    "fft": (78.54, 57.43, 65.40, 72.22),
    "integral": (83.24, 50.38, 48.21, 51.99),
    "ring": (98.80, 52.34, 34.84, 81.20),
    "shape-context": (92.35, 70.95, 63.72, 35.37),
    "scanline": (67.59, 50.48, 41.42, 38.98),
    "mrm": (97.20, 60.52, 77.95, 81.76),
    "tangent": (39.08, 58.94, 18.38, 30.37),
    "flirt": (97.84, 31.99, 16.12, 43.01),
}
"""Table I: Bull's eye [%] on Box, Surface, MPEG-7 (all 1,400 shapes), Robot."""

PAPER_TIME_MS: dict[str, float] = {
    "fft": 0.52, "integral": 1.60, "ring": 4.46, "shape-context": 10.47,
    "scanline": 70.79, "mrm": 87.63, "tangent": 15.33, "flirt": 191.23,
}
"""Table I: time [ms] to compare two places including both descriptors (robot set, one
core of a 3.1 GHz Xeon)."""

PAPER_AUC: dict[str, tuple[float, float, float, float]] = {
    "fft": (0.89, 0.73, 0.89, 0.90),
    "integral": (0.91, 0.72, 0.85, 0.85),
    "ring": (0.97, 0.74, 0.80, 0.89),
    "shape-context": (0.93, 0.81, 0.85, 0.68),
    "scanline": (0.86, 0.67, 0.76, 0.71),
    "mrm": (0.98, 0.75, 0.91, 0.93),
    "tangent": (0.65, 0.77, 0.60, 0.65),
    "flirt": (0.98, 0.59, 0.59, 0.70),
}
"""Table II: area under the ROC curve."""

PAPER_FSCORE: dict[str, tuple[float, float, float, float]] = {
    "fft": (0.62, 0.49, 0.57, 0.54),
    "integral": (0.66, 0.43, 0.42, 0.40),
    "ring": (0.86, 0.53, 0.32, 0.68),
    "shape-context": (0.80, 0.61, 0.62, 0.36),
    "scanline": (0.47, 0.43, 0.25, 0.33),
    "mrm": (0.89, 0.54, 0.68, 0.70),
    "tangent": (0.28, 0.44, 0.10, 0.24),
    "flirt": (0.91, 0.35, 0.20, 0.37),
}
"""Table III: best balanced F-score."""


def paper_figure(table: dict[str, tuple[float, ...]], method: str, kind: str) -> float | None:
    """The paper's figure of `method` on data-set `kind`, or None (e.g. the cascade)."""
    row = table.get(method)
    if row is None or kind not in PAPER_COLUMNS:
        return None
    return row[PAPER_COLUMNS.index(kind)]
