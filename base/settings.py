"""One declaration per setting: type, default, description, unit and range in one place.

A settings class is a frozen dataclass deriving from `Settings`; each field is declared with
`setting` (a leaf) or `section` (a nested settings class):

    @dataclass(frozen=True)
    class PnpParams(Settings):
        reprojection_px: float = setting(3.0, "RANSAC inlier threshold of a PnP correspondence",
                                         unit="px", low=0, low_open=True)
        refine: RefineParams = section(RefineParams, "joint refinement of the accepted pose")

`Settings.__post_init__` checks every field against its declaration (a number's type and
range, a `Literal`'s choices, each item of a tuple) and raises `SettingError` naming the
field, the value and what is allowed; the loader prefixes the dotted key and the file. A class
overrides `check_relations` only for rules that relate fields to each other (min < max). The
descriptions, units and ranges are what `litevloc config show` and docs/parameters.md print.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import types
import typing
from collections.abc import Callable
from typing import Any, Literal

from litevloc.base.errors import LiteVLocError

_SPEC = "litevloc.setting"


class SettingError(LiteVLocError, ValueError):
    """A setting's value is outside its declaration; `key` is the field's name (the loader
    prefixes the dotted path of its section)."""

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        super().__init__(f"{key} must be {allowed}, got {value!r}")
        self.key, self.value, self.allowed = key, value, allowed


@dataclasses.dataclass(frozen=True)
class Spec:
    """What one declaration says besides its type and default."""

    # what the setting does, readable without the neighbouring settings
    description: str
    # unit of a physical quantity ("" = a count, ratio, switch or name)
    unit: str = ""
    # smallest allowed value of a number (None = no lower bound)
    low: float | None = None
    # largest allowed value of a number (None = no upper bound)
    high: float | None = None
    # the lower bound itself is not allowed
    low_open: bool = False
    # the upper bound itself is not allowed
    high_open: bool = False
    # a value allowed besides the range, meaning "off" (0 for `0 = off, else in [16, 16384]`; it may
    # be inf, for a gate code opens: a configuration file gives finite numbers only)
    off: float | None = None
    # a nested settings class, not a leaf
    is_section: bool = False

    @property
    def has_range(self) -> bool:
        return self.low is not None or self.high is not None

    def range_text(self) -> str:
        """The allowed interval as `[0, 1)`, `(0, inf)`; "" without a range."""
        if not self.has_range:
            return ""
        lo = "-inf" if self.low is None else _num(self.low)
        hi = "inf" if self.high is None else _num(self.high)
        left = "(" if self.low_open or self.low is None or math.isinf(self.low) else "["
        right = ")" if self.high_open or self.high is None or math.isinf(self.high) else "]"
        return (f"{_num(self.off)} or " if self.off is not None else "") + f"{left}{lo}, {hi}{right}"

    def admits(self, v: float) -> bool:
        if self.off is not None and v == self.off:
            return True
        if self.low is not None and not (v > self.low if self.low_open else v >= self.low):
            return False
        return self.high is None or (v < self.high if self.high_open else v <= self.high)


def _num(v: float) -> str:
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))


def setting(default: Any = dataclasses.MISSING, description: str = "", *, unit: str = "",
            low: float | None = None, high: float | None = None, low_open: bool = False,
            high_open: bool = False, off: float | None = None) -> Any:
    """A leaf setting: its default (MISSING = required), a description that stands alone, the unit
    of a physical quantity, and the allowed range of a number (closed ends unless `*_open`; for a
    tuple, of each item; `off`: one more value allowed outside it, meaning off). A `Literal`
    annotation gives the choices."""
    spec = Spec(description, unit, low, high, low_open, high_open, off)
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata={_SPEC: spec})
    return dataclasses.field(default=default, metadata={_SPEC: spec})


def section(factory: Callable[[], Any], description: str) -> Any:
    """A nested settings section; `factory` (its class, or a function giving the default instance
    where it differs from the class's defaults) makes the default."""
    return dataclasses.field(default_factory=factory, metadata={_SPEC: Spec(description, is_section=True)})


def spec_of(f: dataclasses.Field[Any]) -> Spec | None:
    """The declaration of a field, None for a field not declared with `setting`/`section`."""
    spec = f.metadata.get(_SPEC)
    return spec if isinstance(spec, Spec) else None


_Check = Callable[[Any], str | None]


class Settings:
    """Base of the settings classes: validates every declared field after construction."""

    def __post_init__(self) -> None:
        for name, check in _checks(type(self)):
            value = getattr(self, name)
            allowed = check(value)
            if allowed is not None:
                raise SettingError(name, value, allowed)
        self.check_relations()

    def check_relations(self) -> None:
        """Rules between fields (raise ValueError naming them); each field's own range is declared."""


_CHECKS: dict[type, list[tuple[str, _Check]]] = {}


def _checks(cls: type) -> list[tuple[str, _Check]]:
    """The checks of each declared field of `cls`, built once per class."""
    found = _CHECKS.get(cls)
    if found is None:
        hints = typing.get_type_hints(cls)
        found = []
        for f in dataclasses.fields(cls):
            spec = spec_of(f)
            check = None if spec is None or spec.is_section else _check_for(hints[f.name], spec)
            if check is not None:
                found.append((f.name, check))
        _CHECKS[cls] = found
    return found


def _check_for(tp: Any, spec: Spec) -> _Check | None:
    """A function value -> None (allowed) or what is allowed, for annotation `tp`; None when the
    declaration checks nothing for it (a string, a switch, a number without a range)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        inner = _check_for(args[0], spec) if len(args) == 1 else None
        return None if inner is None else functools.partial(_unless_none, check=inner)
    if origin is tuple:
        items = typing.get_args(tp)
        item = items[0] if len(set(items) - {Ellipsis}) == 1 else None
        inner = None if item is None else _check_for(item, spec)
        return None if inner is None else functools.partial(_each, check=inner)
    if origin is Literal:
        return functools.partial(_one_of, choices=typing.get_args(tp))
    if tp in (int, float) and spec.has_range:
        return functools.partial(_check_number, spec=spec, integral=tp is int)
    return None


def _unless_none(v: Any, check: _Check) -> str | None:
    return None if v is None else check(v)


def _each(v: Any, check: _Check) -> str | None:
    return next((f"{why} (each item)" for x in v if (why := check(x)) is not None), None)


def _one_of(v: Any, choices: tuple[Any, ...]) -> str | None:
    return None if v in choices else f"one of {list(choices)}"


def _check_number(v: Any, spec: Spec, integral: bool) -> str | None:
    # exact int/float first: the numbers ABCs (numpy scalars) are slower to test
    number = type(v) is int or (type(v) is float and not integral) or (
        not isinstance(v, bool) and isinstance(v, numbers.Integral if integral else numbers.Real))
    if not number or not (math.isfinite(float(v)) or float(v) == spec.off) or not spec.admits(float(v)):
        return f"{'an integer' if integral else 'a finite number'} in {spec.range_text()}"
    return None
