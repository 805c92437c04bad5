"""One switch for the free-space test's keys (`loopclosure.free_space_rule`), and the
scans' model left out, never an error, when the host gives no submap origins."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from data.sim import simulate_run
from loopclosure.free_space import SCAN_FREE_SPACE
from loopclosure.geometric_check import GeometricCheckConfig
from loopclosure.loop_config import LoopClosureConfig
from loopclosure.loop_detector import LoopClosureDetector

FALLBACK = {"free_space_origins": "scans", "free_space_confirm": True,
            "min_consistency": 0.949, "free_space_either": 0.92,
            "free_space_fallback": True}

# -- the switch ---------------------------------------------------------------------------


def test_the_fallback_rule_sets_the_five_keys_and_reads_as_plain_keys() -> None:
    cfg = GeometricCheckConfig(free_space_rule="fallback")
    assert {k: getattr(cfg, k) for k in FALLBACK} == FALLBACK
    assert cfg.free_space_rule == "keys" and cfg.resolved_free_space_rule == "fallback"
    assert cfg == GeometricCheckConfig(**FALLBACK)  # the same config as the five keys
    # other keys are untouched
    assert cfg.min_fitness == GeometricCheckConfig().min_fitness
    # a copy changes one key at a time (the rule is not applied again)
    copy = dataclasses.replace(cfg, min_consistency=0.92)
    assert copy.min_consistency == 0.92 and copy.free_space_origins == "scans"
    assert copy.resolved_free_space_rule == "keys"


def test_the_default_is_the_keys_each_at_its_default() -> None:
    cfg = GeometricCheckConfig()
    assert cfg.free_space_rule == "keys" and cfg.resolved_free_space_rule == "default"
    assert (cfg.free_space_origins, cfg.min_consistency, cfg.free_space_either,
            cfg.free_space_confirm, cfg.free_space_fallback) == ("keyframe", 0.92, 0.0,
                                                                 False, False)
    expert = GeometricCheckConfig(free_space_origins="scans", min_consistency=0.95)
    assert expert.resolved_free_space_rule == "keys" and expert.min_consistency == 0.95


def test_a_key_set_against_the_rule_is_named_in_the_error() -> None:
    with pytest.raises(UserError) as err:
        GeometricCheckConfig(free_space_rule="fallback", min_consistency=0.95,
                             free_space_either=0.9, free_space_origins="scans")
    text = str(err.value)
    assert "loops.check.min_consistency = 0.95" in text
    assert "loops.check.free_space_either = 0.9" in text
    assert "loops.check.min_consistency = 0.949" in text  # the rule's value
    assert "free_space_origins" not in text  # the rule's own value: no conflict
    # a key given at the rule's own value is no conflict
    same = GeometricCheckConfig(free_space_rule="fallback", min_consistency=0.949)
    assert same.resolved_free_space_rule == "fallback"
    with pytest.raises(UserError, match="free_space_rule must be one of keys, fallback"):
        GeometricCheckConfig(free_space_rule="either")


def test_the_switch_on_the_command_line_equals_the_five_keys() -> None:
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, from_dict, to_dict

    one = apply_overrides(PipelineConfig(), ["loops.check.free_space_rule=fallback"])
    five = apply_overrides(PipelineConfig(),
                           [f"loops.check.{k}={v}" for k, v in FALLBACK.items()])
    assert one == five and one != PipelineConfig()
    assert from_dict(PipelineConfig, to_dict(one)) == one  # a dumped config reads back
    with pytest.raises(UserError, match=r"loops\.check\.free_space_either = 0\.5"):
        apply_overrides(PipelineConfig(), ["loops.check.free_space_rule=fallback",
                                           "loops.check.free_space_either=0.5"])


# -- no submap origins: the keyframe model, as the default ---------------------------------


@pytest.fixture(scope="module")
def kidnapped():
    """The box world's first 70 keyframes (every 4th scan; a revisit from keyframe 59
    on), submaps of 7 keyframes placed by the true poses, and estimates that jump 40 m
    after keyframe 30: the revisit is checked with no prior, where the free-space
    test decides."""
    run = simulate_run("box", seed=0)
    kfs = run.scans[::4][:70]
    poses = run.ground_truth.xytheta()[::4][:70]

    def submap(k: int) -> np.ndarray:
        near = range(max(0, k - 3), min(len(kfs), k + 4))
        return np.vstack([se2.transform_points(se2.between(poses[k], poses[j]),
                                               kfs[j].points()) for j in near])

    jumped = poses.copy()
    jumped[31:, 0] += 40.0
    return kfs, jumped, submap


def _loops(kfs, poses, submap, config: LoopClosureConfig):
    """Every keyframe added, the revisit's keyframes (50 on) detected: each
    candidate's verdict and fit."""
    det = LoopClosureDetector(config, submap=submap)  # no submap_origins callback
    for key, scan in enumerate(kfs):
        det.add_keyframe(key, scan.stamp, scan)
    found = [repr((c.query, c.match, c.source, c.accepted, c.reason, c.relative.tolist(),
                   c.covariance.tolist(), c.fused_score, c.prior,
                   None if c.verification is None else c.verification.consistency))
             for key in range(50, len(kfs)) for c in det.detect(key, poses[: key + 1])]
    return det, found


def test_without_submap_origins_the_fallback_finds_the_defaults_loops(kidnapped) -> None:
    kfs, poses, submap = kidnapped
    _, default = _loops(kfs, poses, submap, LoopClosureConfig())
    option = LoopClosureConfig(check=GeometricCheckConfig(free_space_rule="fallback"))
    det, fallback = _loops(kfs, poses, submap, option)  # never raises
    assert fallback == default
    # loops checked with no prior (the correlative check and its free-space test)
    assert sum("'appearance', True, 'accepted'" in c for c in default) >= 5
    # the submaps travel as plain points; the ranges wait for a callback
    assert type(det._submap_points(60)) is np.ndarray
    assert SCAN_FREE_SPACE not in det._target(10).derived
    assert len(det._scan_ranges) == len(kfs)
    det.set_submap_origins(lambda key: (np.array([key]), np.zeros((1, 3))))
    assert det._target(10).derived[SCAN_FREE_SPACE].poses.shape == (1, 3)
