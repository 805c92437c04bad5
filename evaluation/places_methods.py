"""The methods of the place-recognition benchmark: names and how each matcher is built.

A method is a matcher name of `loopclosure.matchers` (the paper's eight) or
``cascade`` (`loopclosure.cascade.CascadeMatcher`).  A method whose module is missing
(or does not define its class yet) raises ImportError / AttributeError here, which
the benchmark reports as *unavailable*.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from data.errors import UserError
from loopclosure.matchers import MATCHER_NAMES, Matcher, matcher_class

ALL_METHODS: tuple[str, ...] = tuple(dict.fromkeys((*MATCHER_NAMES, "cascade")))
"""Every method `--methods all` runs: the paper's eight in its order, then the cascade."""

_CASCADE = ("loopclosure.cascade", "CascadeMatcher")


def parse_methods(text: str) -> list[str]:
    """Method names from ``"all"`` or a comma-separated list (order kept, duplicates dropped)."""
    parts = [p.strip().lower() for p in text.split(",") if p.strip()]
    if not parts:
        raise UserError("--methods needs at least one method (or all)")
    if "all" in parts:
        if parts != ["all"]:
            raise UserError(f"--methods: 'all' cannot be combined with names, got {text!r}")
        return list(ALL_METHODS)
    unknown = [p for p in parts if p not in ALL_METHODS]
    if unknown:
        raise UserError(
            f"unknown method(s) {', '.join(unknown)}: choose all or any of "
            + ",".join(ALL_METHODS)
        )
    return list(dict.fromkeys(parts))


def method_class(name: str) -> type[Matcher]:
    """The matcher class of `name`; ImportError/AttributeError when its module is absent.

    Raises:
        UserError: `name` is not a method (`ALL_METHODS`).
    """
    if name in MATCHER_NAMES:
        return matcher_class(name)
    if name != "cascade":
        raise UserError(f"unknown method {name!r}: choose any of {','.join(ALL_METHODS)}")
    module, cls = _CASCADE  # a registry without the cascade
    return getattr(import_module(module), cls)


def build_matcher(name: str, overrides: dict[str, Any]) -> Matcher:
    """``method_class(name)(**overrides)``."""
    return method_class(name)(**overrides)


def method_overrides(name: str, scale_invariant: bool) -> tuple[dict[str, Any], str | None]:
    """Config overrides for `name` on a data set, and a note when one could not be applied.

    ``cascade`` on places (not scale invariant) runs with the SLAM pipeline's place
    database stages (`loopclosure.cascade.place_database_stages`).

    Raises ImportError/AttributeError when the method is unavailable.
    """
    cls = method_class(name)
    if not scale_invariant:
        if name == "cascade":  # laser places: the pipeline's own cascade
            from loopclosure.cascade import place_database_stages

            return place_database_stages(), None
        return {}, None
    try:
        cls(scale_invariant=True)
    except UserError:  # the matcher has no such option
        return {}, f"{name} has no scale_invariant option: run as configured"
    return {"scale_invariant": True}, None
