"""Each package's front door: every exported name resolves, and the README's imports work."""

from __future__ import annotations

import importlib

import pytest

import data
import evaluation
import loopclosure
import slam
from data.errors import DataError, LoopClosureError, UserError


@pytest.mark.parametrize(
    "package", [data, loopclosure, slam, evaluation], ids=lambda p: p.__name__
)
def test_every_exported_name_resolves(package) -> None:
    for name in package.__all__:
        assert getattr(package, name) is not None, name
    assert len(set(package.__all__)) == len(package.__all__)
    homes = getattr(package, "_HOMES", None)
    if homes is not None:  # a lazy front door exports exactly what it can load
        assert set(homes) == set(package.__all__)


def test_front_door_names_are_the_deep_objects() -> None:
    from data.sources import open_source
    from loopclosure.loop_detector import LoopClosureDetector
    from slam.pipeline import Mapper

    assert loopclosure.LoopClosureDetector is LoopClosureDetector
    assert slam.Mapper is Mapper
    assert data.open_source is open_source


def test_version_comes_from_the_package_metadata() -> None:
    from importlib.metadata import version

    assert loopclosure.__version__ == version("loopclosure")
    assert loopclosure.__version__.count(".") >= 2


def test_one_exception_base_for_every_deliberate_error() -> None:
    assert issubclass(UserError, LoopClosureError) and issubclass(UserError, ValueError)
    assert issubclass(DataError, UserError)
    assert issubclass(loopclosure.DegeneratePolygonError, LoopClosureError)
    with pytest.raises(LoopClosureError, match="nonsense"):
        loopclosure.get_matcher("nonsense")
    with pytest.raises(LoopClosureError, match="keyframes must be added in order"):
        loopclosure.LoopClosureDetector().add_keyframe(3, 0.0, None)


def test_unknown_attribute_of_the_lazy_front_door_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'Nonsense'"):
        slam.Nonsense  # noqa: B018
    assert "Mapper" in dir(importlib.import_module("slam"))
    assert "relations_metric" in dir(evaluation)


def test_the_cli_starts_without_the_heavy_libraries() -> None:
    import subprocess
    import sys

    code = "import sys, slam.cli.main, evaluation; print('gtsam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
