"""`benchmarks/robust_isam_updates.py`: the iSAM2 updates' bands and the counted run."""

from __future__ import annotations

import numpy as np

from evaluation.robustness import inject_false_loops
from slam.consistency import admit_incrementally
from slam.isam_prefix import IsamPrefix
from slam.least_squares import StickySolver
from slam.optimize import initial_guess
from tests.helpers import load_benchmark
from tests.test_backend import _square_graph


def test_band_rows_split_updates_by_new_factors_then_poses_relinearised() -> None:
    bench = load_benchmark("robust_isam_updates")
    updates = [(True, 40, 10, 0.5), (False, 0, 0, 0.01), (False, 7, 30, 0.25),
               (False, 1500, 2000, 2.0), (False, 2500, 3000, 3.0), (True, 2, 4, 0.5)]
    rows = {label: rest for label, *rest in bench.band_rows(updates)}
    # by hand: two updates with new factors (1.0 s, re-eliminated 10 and 4: mean 7); one
    # that relinearised nothing; one of 7 poses; two over 1000 (5.0 s, mean 2500)
    assert rows["with new factors"] == [2, 1.0, 7.0]
    assert rows["relinearised 0-0"] == [1, 0.01, 0.0]
    assert rows["relinearised 1-10"] == [1, 0.25, 30.0]
    assert rows["relinearised 11-100"] == [0, 0.0, 0.0]
    assert rows["relinearised 1001-more"] == [2, 5.0, 2500.0]
    assert bench.band_rows([]) == []


def test_the_counted_run_decides_as_the_plain_one_and_counts_every_update() -> None:
    bench = load_benchmark("robust_isam_updates")
    graph, _ = _square_graph(noise=0.02, laps=2)
    corrupted, _ = inject_false_loops(graph, 0.5, np.random.default_rng(2))
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))

    def run():  # type: ignore[no-untyped-def]
        return admit_incrementally(corrupted, values, block=10, prefix_solver="isam2",
                                   solver=StickySolver())

    plain = run()
    originals = bench.install()
    try:
        counted = run()
    finally:
        bench.restore(originals)
    assert IsamPrefix.solve is originals[2]
    np.testing.assert_array_equal(plain.weights, counted.weights)
    assert bench.UPDATES  # the prefix was solved by iSAM2
    assert sum(v[1] for v in bench.PREFIX.values()) == len(bench.UPDATES)
    assert sum(v[0] for v in bench.PREFIX.values()) == sum(p[4] for p in bench.PASSES.values())
    # every solve ends on an update that relinearises nothing unless it stopped converging
    exits = sum(1 for new, relin, _, _ in bench.UPDATES if not new and relin == 0)
    assert exits <= sum(v[0] for v in bench.PREFIX.values())
