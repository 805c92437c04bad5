"""The place-recognition benchmark runner and its `bench places` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import typer

import evaluation.places_benchmark as pb
from data.errors import DataWarning, UserError
from evaluation import places_methods, places_paper, places_report
from evaluation.place_datasets import PlaceSet, sim_places
from evaluation.retrieval import best_fscore, bullseye, roc_auc
from loopclosure.matchers import get_matcher
from loopclosure.matchers.base import Matcher
from loopclosure.polygon import Polygon

CONTRACT_KEYS = {"bullseye", "auc", "fscore", "ms_per_pair", "ms_describe", "ms_compare"}


@pytest.fixture(scope="module")
def tiny() -> PlaceSet:
    """Box world, 3 places x 4 scans (360-degree polygons)."""
    return sim_places("box", seed=0, places=3, scans_per_place=4)


# ---------------------------------------------------------------- methods and paper


def test_parse_methods() -> None:
    assert places_methods.parse_methods("all") == list(places_methods.ALL_METHODS)
    assert places_methods.ALL_METHODS[:8] == ("fft", "integral", "ring", "shape-context",
                                              "scanline", "mrm", "tangent",
                                              "flirt")  # the paper's row order
    assert places_methods.ALL_METHODS[-1] == "cascade"
    assert places_methods.parse_methods(" ring, fft ,ring") == ["ring", "fft"]
    with pytest.raises(UserError, match="unknown method"):
        places_methods.parse_methods("fft,sift")
    with pytest.raises(UserError, match="cannot be combined"):
        places_methods.parse_methods("all,fft")
    with pytest.raises(UserError, match="at least one"):
        places_methods.parse_methods(" , ")


def test_an_unknown_method_class_is_a_user_error() -> None:
    with pytest.raises(UserError, match="unknown method 'sift'"):
        places_methods.method_class("sift")
    assert places_methods.method_class("cascade").__name__ == "CascadeMatcher"


def test_the_cascade_on_places_is_the_pipelines_place_database() -> None:
    from loopclosure.cascade import CascadeConfig, CascadeMatcher
    from loopclosure.place_config import PlaceDatabaseConfig

    overrides, note = places_methods.method_overrides("cascade", scale_invariant=False)
    cfg = CascadeMatcher(**overrides).config
    base = PlaceDatabaseConfig()
    assert note is None
    assert (cfg.prefilter, cfg.verifiers, cfg.logistic) == (
        base.prefilter, base.verifiers, base.logistic)
    assert cfg.resolved_fusion == "logistic" and not cfg.anchored
    row = pb.MethodResult("cascade", 1.0, 1.0, 1.0, 0, 0, 0, 0, 0, np.zeros((1, 1)), overrides)
    assert json.loads(json.dumps(row.to_json()))["config"]["logistic"]["names"] == ["pairs",
                                                                                  "flirt"]
    # Shape sets keep the paper's stages, scale invariant.
    overrides, _ = places_methods.method_overrides("cascade", scale_invariant=True)
    assert overrides == {"scale_invariant": True}
    assert CascadeMatcher(**overrides).config.prefilter == CascadeConfig().prefilter
    assert places_methods.method_overrides("flirt", scale_invariant=False) == ({}, None)


def test_paper_figures() -> None:
    """Spot checks of the copied Tables I-III (column order Box, Surface, MPEG-7, Robot)."""
    assert places_paper.paper_figure(places_paper.PAPER_BULLSEYE, "mrm", "mpeg7") == 77.95
    assert places_paper.paper_figure(places_paper.PAPER_BULLSEYE, "ring", "box") == 98.80
    assert places_paper.paper_figure(places_paper.PAPER_AUC, "shape-context", "surface") == 0.81
    assert places_paper.paper_figure(places_paper.PAPER_FSCORE, "flirt", "robot") == 0.37
    assert places_paper.PAPER_TIME_MS["flirt"] == 191.23
    assert places_paper.paper_figure(places_paper.PAPER_BULLSEYE, "cascade", "box") is None
    for table in (places_paper.PAPER_BULLSEYE, places_paper.PAPER_AUC, places_paper.PAPER_FSCORE):
        assert list(table) == list(places_methods.ALL_METHODS[:8])


# ---------------------------------------------------------------- runner


def test_run_places_fft_ring(tiny: PlaceSet) -> None:
    result = pb.run_places(tiny, ["fft", "ring"], seed=0)
    doc = result.to_json()
    assert doc["dataset"] == "box" and doc["shapes"] == 12 and doc["classes"] == 3
    assert set(doc["methods"]) == {"fft", "ring"} and doc["unavailable"] == []
    for name, m in doc["methods"].items():
        assert CONTRACT_KEYS <= set(m)
        assert 0.0 <= m["bullseye"] <= 100.0 and 0.0 <= m["auc"] <= 1.0
        assert 0.0 < m["fscore"] <= 1.0
        assert m["ms_describe"] > 0 and m["ms_compare"] > 0 and m["ms_compare_single"] > 0
        assert m["ms_per_pair"] == pytest.approx(2 * m["ms_describe"] + m["ms_compare"])
        r = result.methods[name]
        # the matrix is the matcher's own all-pairs matrix, and the measures are of it
        matcher = get_matcher(name)
        want = matcher.pairwise([matcher.describe(p) for p in tiny.polygons])
        assert np.allclose(r.distances, want)
        assert r.bullseye == bullseye(want, tiny.labels)
        assert r.auc == roc_auc(want, tiny.labels)
        assert r.fscore == best_fscore(want, tiny.labels)
    # the same place recognised: three well separated places in a box world
    assert result.methods["ring"].bullseye > 80.0


def test_workers_two_equal_one(tiny: PlaceSet) -> None:
    one = pb.run_places(tiny, ["fft", "ring"], workers=1)
    two = pb.run_places(tiny, ["fft", "ring"], workers=2)
    assert not two.failed, two.failed
    for name in ("fft", "ring"):
        assert np.array_equal(one.methods[name].distances, two.methods[name].distances)
        a, b = one.methods[name].to_json(), two.methods[name].to_json()
        for key in ("bullseye", "auc", "fscore"):
            assert a[key] == b[key]
        assert b["ms_compare"] > 0


def test_unavailable_and_failed_methods(tiny: PlaceSet, monkeypatch) -> None:
    real = places_methods.matcher_class

    class NaNMatcher(Matcher):
        name = "nan"

        def describe(self, polygon: Polygon) -> np.ndarray:
            return np.array([polygon.area])

        def distance(self, a, b) -> float:
            return float("nan")

        def distances(self, query, stacked) -> np.ndarray:
            return np.full(len(stacked), np.nan)

    def fake(name: str):
        if name == "mrm":
            raise ModuleNotFoundError("No module named 'loopclosure.matchers.mrm'")
        if name == "tangent":
            return NaNMatcher
        return real(name)

    monkeypatch.setattr(places_methods, "matcher_class", fake)
    with pytest.warns(DataWarning) as caught:
        result = pb.run_places(tiny, ["mrm", "tangent", "fft"])
    assert set(result.methods) == {"fft"}
    assert list(result.unavailable) == ["mrm"] and "No module" in result.unavailable["mrm"]
    assert "not finite" in result.failed["tangent"]
    assert len(caught) == 2  # one warning for unavailable, one for failed
    doc = result.to_json()
    assert doc["unavailable"] == ["mrm"] and "tangent" in doc["failed"]


def test_scale_invariant_sets_turn_the_option_on(tiny: PlaceSet) -> None:
    polys, labels, desc = tiny
    mp = PlaceSet(polys, labels, {**desc, "scale_invariant": True, "kind": "mpeg7",
                                  "name": "mpeg7:fake"})
    result = pb.run_places(mp, ["fft"])
    assert result.methods["fft"].overrides == {"scale_invariant": True}
    assert result.to_json()["methods"]["fft"]["config"] == {"scale_invariant": True}
    assert pb.run_places(tiny, ["fft"]).methods["fft"].overrides == {}


def test_report_files(tiny: PlaceSet, tmp_path: Path) -> None:
    result = pb.run_places(tiny, ["fft", "ring"])
    result.unavailable["cascade"] = "ModuleNotFoundError: test"
    files = places_report.write_places_report(tmp_path, [result])
    text = (tmp_path / "report.md").read_text()
    for must in ("Table I", "Table II", "Table III", "Box ours", "Box paper", "78.54", "0.97",
                 "0.86", f"{result.methods['ring'].bullseye:.2f}", "roc_box.png", "n/a"):
        assert must in text, must
    for key in ("roc_box", "pr_box"):
        assert files[key].stat().st_size > 1000
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["dataset"] == "box" and set(doc["methods"]) == {"fft", "ring"}
    assert doc["paper"]["bullseye"]["fft"] == [78.54, 57.43, 65.40, 72.22]
    # several data sets: one column pair per set (2 sets x 3 tables)
    two = places_report.write_places_report(tmp_path / "two", [result, result])
    text = two["report"].read_text()
    assert text.count("Box (box) ours") == 6 and (tmp_path / "two" / "roc_box2.png").exists()
    assert "datasets" in json.loads((tmp_path / "two" / "results.json").read_text())
    lines = places_report.summary_lines(result)
    assert lines[0].startswith("box: 12 shapes, 3 classes") and "unavailable" in lines[-1]


# ---------------------------------------------------------------- command line


@pytest.fixture()
def cli(monkeypatch):
    """``main(argv) -> exit status`` of the real entry point, with `bench places` registered."""
    import slam.cli.main as entry
    from evaluation.cli_places import register

    def build() -> typer.Typer:
        app = typer.Typer(add_completion=False, no_args_is_help=True,
                          pretty_exceptions_enable=False)
        bench = typer.Typer(no_args_is_help=True)
        register(bench)
        app.add_typer(bench, name="bench")

        @app.callback()
        def root() -> None:
            """Test root."""

        return app

    monkeypatch.setattr(entry, "build_app", build)
    return entry.main


def test_cli_json(cli, capsys) -> None:
    status = cli(["bench", "places", "--dataset", "box", "--methods", "fft,ring", "--json"])
    out = capsys.readouterr().out
    assert status == 0
    doc = json.loads(out)
    assert doc["dataset"] == "box" and doc["shapes"] == 231 and doc["classes"] == 11
    assert set(doc["methods"]) == {"fft", "ring"}
    for m in doc["methods"].values():
        assert CONTRACT_KEYS <= set(m)
        assert 50.0 < m["bullseye"] <= 100.0  # well above chance (2 x 21 of 231: 18 %)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--dataset", "box", "--methods", "fft,sift"], "unknown method"),
        (["--dataset", "kitchen", "--methods", "fft"], "unknown data set"),
        (["--dataset", "box", "--methods", "fft", "--workers", "0"], "--workers"),
        (["--dataset", "mpeg7:{tmp}", "--methods", "fft"], "no image files"),
        (["--dataset", "robot:{tmp}", "--methods", "fft"], "no corrected CARMEN logs"),
        (["--dataset", "mpeg7:{tmp}/missing", "--methods", "fft"], "no such folder"),
    ],
)
def test_cli_bad_input_exits_2(cli, capsys, tmp_path: Path, args: list[str],
                               message: str) -> None:
    argv = ["bench", "places", *[a.format(tmp=tmp_path) for a in args]]
    status = cli(argv)
    err = capsys.readouterr().err
    assert status == 2
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and message in lines[0], err
    assert "Traceback" not in err
