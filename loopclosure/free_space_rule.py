"""The free-space test's rules: one switch for the keys of the geometric check that
move together (`loopclosure.geometric_check.GeometricCheckConfig.free_space_rule`).

The test (`loopclosure.free_space`) is set by five keys of the check:
``free_space_origins``, ``free_space_confirm``, ``min_consistency``,
``free_space_either`` and ``free_space_fallback``.  A rule names a coherent set of
their values:

- ``keys``: the five keys as given, each at its own default unless set (the default:
  the keyframe model (1) at ``min_consistency``); for experts.
- ``fallback``: the keyframe model (1) at 0.92 decides every query it serves; the
  scans' model confirmed by (1) ((5), at 0.949) only adds places to a query none of
  whose places (1) passes.  A pair lacking the scans' free space (a host without the
  ``submap_origins`` callback) is judged by (1) at 0.92, as by the default.

A rule is expanded when the config is made: the config then holds the rule's values
and ``keys``, so that a copy (`dataclasses.replace`, a dumped config read back)
reproduces or changes them key by key.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from data.errors import UserError

FREE_SPACE_RULES: dict[str, dict[str, Any]] = {
    "keys": {},
    "fallback": {
        "free_space_origins": "scans",
        "free_space_confirm": True,
        "min_consistency": 0.949,
        "free_space_either": 0.92,
        "free_space_fallback": True,
    },
}
"""Each rule's values of the check's keys (``keys``: none, the keys as given)."""

PREFIX = "loops.check."


def expand_free_space_rule(cfg: Any) -> None:
    """Set `cfg`'s keys (a `GeometricCheckConfig`, in place) to the values of its
    ``free_space_rule``, then the rule to ``keys``.

    A key left at its field default takes the rule's value; a key set to another
    value than both conflicts with the rule.

    Raises:
        UserError: an unknown rule, or keys that conflict with it (named, with the
            values given and the rule's).
    """
    rule = cfg.free_space_rule
    if rule not in FREE_SPACE_RULES:
        raise UserError(f"{PREFIX}free_space_rule must be one of "
                        f"{', '.join(FREE_SPACE_RULES)}, got {rule!r}")
    values = FREE_SPACE_RULES[rule]
    defaults = {f.name: f.default for f in dataclasses.fields(cfg)}
    conflicts = [name for name, value in values.items()
                 if getattr(cfg, name) != defaults[name] and getattr(cfg, name) != value]
    if conflicts:
        given = ", ".join(f"{PREFIX}{n} = {getattr(cfg, n)!r}" for n in conflicts)
        wanted = ", ".join(f"{PREFIX}{n} = {values[n]!r}" for n in conflicts)
        raise UserError(f"{PREFIX}free_space_rule = {rule} sets {wanted}; the config sets "
                        f"{given}: leave those keys out, or set {PREFIX}free_space_rule = "
                        "keys to set each key yourself")
    for name, value in values.items():
        setattr(cfg, name, value)
    cfg.free_space_rule = "keys"


def free_space_rule_of(cfg: Any) -> str:
    """The rule whose values `cfg`'s keys hold: ``fallback``, ``default`` (every key
    at its field default) or ``keys`` (any other combination)."""
    defaults = {f.name: f.default for f in dataclasses.fields(cfg)}
    if all(getattr(cfg, n) == v for n, v in FREE_SPACE_RULES["fallback"].items()):
        return "fallback"
    if all(getattr(cfg, n) == defaults[n] for n in FREE_SPACE_RULES["fallback"]):
        return "default"
    return "keys"
