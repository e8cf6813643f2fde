"""Typed settings from TOML: a dataclass's fields set from a table, each value converted to the
field's annotated type by msgspec, with a one-line ConfigError naming the key of anything
wrong."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, Literal

import msgspec

from activetouch.errors import ConfigError

# How a wrong value is described, by the field's type.
_EXPECTED = {int: "an integer", float: "a number", bool: "true/false", str: "a string"}


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """`value` as type `tp` (msgspec's lax conversion: "3" is an int, "true" a bool, a word
    of a `Literal` is checked), else a ConfigError naming `key`."""
    try:
        return msgspec.convert(value, tp, strict=False)
    except msgspec.ValidationError as e:
        origin = typing.get_origin(tp)
        if origin is Literal:
            allowed = ", ".join(map(str, typing.get_args(tp)))
            raise ConfigError(f"{key}: {value!r} is not one of {allowed}") from None
        if tp in _EXPECTED:
            raise ConfigError(f"{key}: expected {_EXPECTED[tp]}, got {value!r}") from None
        if origin is list:  # msgspec says which element: "Expected `int`, got `str` - at `$[1]`"
            raise ConfigError(f"{key}: expected a list ({e}), got {value!r}") from None
        raise ConfigError(f"{key}: {e} (got {value!r})") from None


def apply_section(obj: Any, data: dict[str, Any], prefix: str, what: str = "") -> None:
    """Set the fields of dataclass `obj` from `data`, coercing types; ConfigError naming the
    key (`prefix` + name) of anything unknown or of the wrong type."""
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj)}
    for k, v in data.items():
        key = f"{prefix}{k}"
        if k not in names:
            of = f" of {what}" if what else ""
            raise ConfigError(
                f"unknown setting {key!r}{of} (known: {', '.join(sorted(names - {'type'}))})"
            )
        cur = getattr(obj, k)
        if dataclasses.is_dataclass(cur):
            if not isinstance(v, dict):
                raise ConfigError(f"{key}: expected a table of settings")
            apply_section(cur, v, key + ".")
        else:
            setattr(obj, k, _coerce(v, hints[k], key))
