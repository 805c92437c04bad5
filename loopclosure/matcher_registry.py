"""Every matcher by CLI name: the paper's eight (`loopclosure.matchers`), then the cascade.

The cascade (`loopclosure.cascade.CascadeMatcher`) is a place database seen as one
matcher, built from the eight; it sits above them, and so does this registry, the
one place that names all nine.  Benchmarks and CLIs that offer "any matcher" look
names up here; the place database picks its stages from `loopclosure.matchers`.
"""

from __future__ import annotations

from typing import Any

from data.errors import UserError
from loopclosure.cascade import CascadeMatcher
from loopclosure.matchers import MATCHER_NAMES as PAPER_MATCHERS
from loopclosure.matchers import matcher_class as paper_matcher_class
from loopclosure.matchers.base import Matcher

MATCHER_NAMES: tuple[str, ...] = (*PAPER_MATCHERS, CascadeMatcher.name)
"""The paper's eight in its order, then ``cascade``."""


def matcher_class(name: str) -> type[Matcher]:
    """The matcher class registered under `name` (`UserError` listing the names)."""
    if name == CascadeMatcher.name:
        return CascadeMatcher
    if name not in PAPER_MATCHERS:
        raise UserError(f"unknown matcher {name!r}; known: {', '.join(MATCHER_NAMES)}")
    return paper_matcher_class(name)


def get_matcher(name: str, **config: Any) -> Matcher:
    """A matcher instance by CLI name; keyword arguments override its config defaults."""
    return matcher_class(name)(**config)


__all__ = ["MATCHER_NAMES", "get_matcher", "matcher_class"]
