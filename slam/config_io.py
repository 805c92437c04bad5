"""Nested dataclass configs <-> plain dicts, YAML files and ``key.path=value`` overrides.

Every parameter of the pipeline lives in one tree of dataclasses (see
`slam.config`).  This module knows nothing of their contents: it converts any
such tree to a dict and back (unknown keys are errors naming the valid ones),
reads and writes YAML (ruamel.yaml, which rosbags already installs), and applies
command-line overrides such as ``--set places.top_k=20`` with the value converted
to the field's type.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from ruamel.yaml import YAML, YAMLError

from data.atomic_write import atomic_output
from data.errors import UserError

T = TypeVar("T")


def to_dict(config: Any) -> dict[str, Any]:
    """A plain nested dict of a dataclass tree (tuples become lists)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = to_dict(value)
        elif isinstance(value, tuple | list):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """`value` converted to type `hint` (bool, int, float, str, tuples/lists, Optional)."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            if type(None) in args:
                return None
        for option in (a for a in args if a is not type(None)):
            try:
                return _coerce(value, option, where)
            except UserError:
                continue
        raise UserError(f"{where}: cannot read {value!r} as {hint}")
    if origin in (tuple, list):
        items = value.split(",") if isinstance(value, str) else list(value)
        inner = args[0] if args else str
        converted = [_coerce(v.strip() if isinstance(v, str) else v, inner, where) for v in items]
        return tuple(converted) if origin is tuple else converted
    if hint is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "yes", "on", "1"):
            return True
        if isinstance(value, str) and value.lower() in ("false", "no", "off", "0"):
            return False
        raise UserError(f"{where}: expected true or false, got {value!r}")
    if hint in (int, float):
        if isinstance(value, bool):
            raise UserError(f"{where}: expected a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise UserError(f"{where}: expected a number, got {value!r}") from None
        if hint is int:
            if not number.is_integer():
                raise UserError(f"{where}: expected an integer, got {value!r}")
            return int(number)
        return number
    if hint is str:
        return str(value)
    return value


def from_dict(cls: type[T], data: dict[str, Any] | None, where: str = "config") -> T:
    """A `cls` instance from a nested dict; missing keys keep their defaults."""
    data = dict(data or {})
    hints = _field_types(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        raise UserError(
            f"{where}: unknown key(s) {', '.join(unknown)}; valid: {', '.join(sorted(names))}"
        )
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise UserError(f"{where}.{name}: expected a section of keys, got {value!r}")
            kwargs[name] = from_dict(hint, value, f"{where}.{name}")
        else:
            kwargs[name] = _coerce(value, hint, f"{where}.{name}")
    return cls(**kwargs)


def apply_overrides(config: T, overrides: list[str]) -> T:
    """A copy of `config` with ``dotted.key=value`` overrides applied (values typed)."""
    data = to_dict(config)
    for item in overrides:
        if "=" not in item:
            raise UserError(f"--set {item!r}: expected key=value, e.g. places.top_k=20")
        key, value = item.split("=", 1)
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            if part not in node or not isinstance(node[part], dict):
                raise UserError(f"--set {item!r}: no section {part!r} in the config")
            node = node[part]
        if parts[-1] not in node:
            raise UserError(
                f"--set {item!r}: no key {parts[-1]!r}; valid: {', '.join(sorted(node))}"
            )
        node[parts[-1]] = value.strip()
    return from_dict(type(config), data)


def load_config(cls: type[T], path: Path) -> T:
    """Read a YAML config file into `cls` (keys not given keep their defaults)."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read config: {exc.strerror or exc}") from None
    try:
        data = YAML(typ="safe").load(text)
    except YAMLError as exc:
        raise UserError(f"{path}: not valid YAML: {str(exc).splitlines()[0]}") from None
    if data is not None and not isinstance(data, dict):
        raise UserError(f"{path}: a config file must be a mapping of sections")
    return from_dict(cls, data, where=str(path))


def dump_config(config: Any, path: Path) -> None:
    """Write `config` as YAML to `path` (atomically)."""
    yaml = YAML()
    yaml.default_flow_style = False
    with atomic_output(path, "w") as f:
        yaml.dump(to_dict(config), f)
