"""`SubmapConfig.stop_at_kidnap`: a keyframe after a kidnapped odometry increment starts
a submap segment of the mapper (`Mapper._span`), wherever the kidnapped scan falls."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from slam.config import PipelineConfig, SubmapConfig
from slam.pipeline import Mapper


def _feed(mapper: Mapper, scans: list[tuple[bool, bool]]) -> None:
    """Scans as (kidnapped increment before it, becomes a keyframe) through
    `Mapper._note_kidnap`, the keyframes appended as the selector would."""
    kfs = mapper.keyframes.keyframes
    for kidnapped, is_keyframe in scans:
        keyframe = SimpleNamespace(id=len(kfs)) if is_keyframe else None
        if keyframe is not None:
            kfs.append(keyframe)
        mapper._note_kidnap(SimpleNamespace(extra={"kidnap": kidnapped}), keyframe)


# Keyframe 0; a kidnapped scan that is no keyframe, then keyframe 1 (a segment starts);
# keyframe 2; keyframe 3 on a kidnapped scan itself (a segment starts); keyframe 4.
SCANS = [(False, True), (True, False), (False, False), (False, True), (False, True),
         (True, True), (False, False), (False, True)]


@pytest.mark.parametrize("stop, spans", [
    (True, [(0, 0), (1, 2), (1, 2), (3, 4), (3, 4)]),
    (False, [(0, 4)] * 5),
])
def test_a_keyframe_after_a_kidnapped_increment_starts_a_segment(stop, spans) -> None:
    mapper = Mapper(PipelineConfig(submap=SubmapConfig(stop_at_kidnap=stop)))
    _feed(mapper, SCANS)
    assert [mapper._span(k) for k in range(5)] == spans
    assert [mapper._session_span(k) for k in range(5)] == [(0, 4)] * 5


def test_a_kidnap_before_the_first_keyframe_starts_nothing() -> None:
    mapper = Mapper(PipelineConfig(submap=SubmapConfig(stop_at_kidnap=True)))
    _feed(mapper, [(True, False), (True, True), (False, True)])
    assert mapper._span(0) == (0, 1) and mapper._span(1) == (0, 1)
