"""The eight shape matchers of the place-recognition paper behind one interface.

`get_matcher(name)` builds one by its CLI name; `MATCHER_NAMES` lists them in the
paper's order.  Modules are imported lazily so a user of one matcher does not pay
for the others.  The cascade (`loopclosure.cascade`: prefilter, verifiers and score
fusion behind the same interface) is built from these matchers, so it is not one of
them: `loopclosure.matcher_registry` lists all nine.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from data.errors import UserError
from loopclosure.matchers.base import Matcher

_REGISTRY: dict[str, tuple[str, str]] = {
    "fft": ("loopclosure.matchers.fft", "FFTMatcher"),
    "integral": ("loopclosure.matchers.integral_invariant", "IntegralInvariantMatcher"),
    "ring": ("loopclosure.matchers.ring_projection", "RingProjectionMatcher"),
    "shape-context": ("loopclosure.matchers.shape_context", "ShapeContextMatcher"),
    "scanline": ("loopclosure.matchers.scan_line", "ScanLineMatcher"),
    "mrm": ("loopclosure.matchers.mrm", "MRMMatcher"),
    "tangent": ("loopclosure.matchers.tangent_space", "TangentSpaceMatcher"),
    "flirt": ("loopclosure.matchers.flirt", "FlirtMatcher"),
    "pairs": ("loopclosure.matchers.pair_histogram", "PairHistogramMatcher"),
}

MATCHER_NAMES: tuple[str, ...] = tuple(_REGISTRY)


def matcher_class(name: str) -> type[Matcher]:
    """The matcher class registered under `name` (`UserError` listing the names)."""
    try:
        module, cls = _REGISTRY[name]
    except KeyError:
        raise UserError(
            f"unknown matcher {name!r}; known: {', '.join(MATCHER_NAMES)}"
        ) from None
    return getattr(import_module(module), cls)


def get_matcher(name: str, **config: Any) -> Matcher:
    """A matcher instance by CLI name; keyword arguments override its config defaults."""
    return matcher_class(name)(**config)


__all__ = ["MATCHER_NAMES", "Matcher", "get_matcher", "matcher_class"]
