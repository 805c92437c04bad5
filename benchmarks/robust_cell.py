"""The command line of the robustness diagnoses that study one corrupted pose graph.

`cell_parser` gives their common arguments (graph file name, data folder, odometry
scaling, outlier policy, ratio [%], seed, and optionally a cache folder); `read_cell`
reads the cell they name (`evaluation.robustness.corrupted_graph`), keeping the clean
optimum of each graph and scaling in the cache folder between runs (minutes on
M3500a).
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

from evaluation.robustness import corrupted_graph


def cell_parser(description: str, seed: int = 0, cache: bool = True) -> argparse.ArgumentParser:
    """An argument parser with the arguments that name one cell."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("graph")
    parser.add_argument("--data", default="../shared/data/g2o")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--policy", default="random")
    parser.add_argument("--ratio", type=float, default=50.0)
    parser.add_argument("--seed", type=int, default=seed)
    if cache:
        parser.add_argument("--cache", type=Path, default=None)
    return parser


def read_cell(args: argparse.Namespace):
    """``(graph, reference, corrupted, is_false)`` of the cell `args` name
    (`evaluation.robustness.corrupted_graph`), the clean optimum from ``args.cache``
    when it holds it (and stored there when it does not)."""
    folder = getattr(args, "cache", None)
    cached = folder / f"{args.graph}-x{args.scale:g}.pkl" if folder else None
    known = (pickle.loads(cached.read_bytes()) if cached is not None and cached.exists()
             else None)
    cell = corrupted_graph(str(Path(args.data) / args.graph), args.scale, args.ratio / 100,
                           args.policy, args.seed, reference=known)
    if cached is not None and known is None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_bytes(pickle.dumps(cell[1]))
    return cell
