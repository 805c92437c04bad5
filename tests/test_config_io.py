"""Config trees: dict/YAML round trip, typed overrides, clear errors."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from data.errors import UserError
from slam.config_io import apply_overrides, dump_config, from_dict, load_config, to_dict


@dataclass
class Inner:
    top_k: int = 10
    scale: float | None = None
    names: tuple[str, ...] = ("fft", "ring")
    enabled: bool = True


@dataclass
class Outer:
    name: str = "x"
    inner: Inner = field(default_factory=Inner)


def test_round_trip_through_yaml(tmp_path) -> None:
    cfg = Outer("y", Inner(5, 0.5, ("mrm",), False))
    path = tmp_path / "c.yaml"
    dump_config(cfg, path)
    assert load_config(Outer, path) == cfg
    assert to_dict(cfg)["inner"]["names"] == ["mrm"]


def test_overrides_are_typed() -> None:
    cfg = apply_overrides(
        Outer(), ["inner.top_k=20", "inner.scale=0.25", "inner.names=a, b", "inner.enabled=off"]
    )
    assert cfg.inner == Inner(20, 0.25, ("a", "b"), False)
    assert apply_overrides(cfg, ["inner.scale=none"]).inner.scale is None


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("inner.nope=1", "no key 'nope'"),
        ("nope.top_k=1", "no section 'nope'"),
        ("inner.top_k=ten", "expected a number"),
        ("inner.top_k=2.5", "expected an integer"),
        ("inner.enabled=maybe", "expected true or false"),
        ("inner.top_k", "expected key=value"),
    ],
)
def test_bad_overrides_say_what_is_wrong(override: str, message: str) -> None:
    with pytest.raises(UserError, match=message):
        apply_overrides(Outer(), [override])


def test_unknown_keys_in_a_file_list_the_valid_ones(tmp_path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("inner:\n  topk: 3\n")
    with pytest.raises(UserError, match=r"unknown key.*topk.*valid: enabled, names, scale, top_k"):
        load_config(Outer, path)
    assert from_dict(Outer, {"inner": {"top_k": 3}}).inner.top_k == 3


def test_an_unknown_final_start_is_refused_when_the_config_is_made() -> None:
    from slam.config import PipelineConfig

    with pytest.raises(UserError, match=r"backend\.final_start must be one of given, incremental"):
        apply_overrides(PipelineConfig(), ["backend.final_start=fast"])


def test_the_admission_check_mode_is_checked_and_reaches_the_config() -> None:
    from slam.config import PipelineConfig

    assert apply_overrides(PipelineConfig(), ["backend.admission_check=screen"]
                           ).backend.admission_check == "screen"
    with pytest.raises(UserError, match=r"backend\.admission_check must be one of exact, screen"):
        apply_overrides(PipelineConfig(), ["backend.admission_check=fast"])
