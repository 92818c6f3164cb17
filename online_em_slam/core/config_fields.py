"""The declaration of a setting: its default, description and allowed range or choices
(:class:`ParamInfo` in a dataclass field's metadata, :func:`param`), and the checks
every configuration section runs with it."""
from __future__ import annotations

import math
from dataclasses import Field, dataclass, field, fields, replace
from typing import Any


@dataclass(frozen=True)
class ParamInfo:
    """What a setting may be, said once: its description and its range or choices.

    ``lo``/``hi`` bound a number (each entry of a tuple), excluded where
    ``lo_open``/``hi_open``; ``choices`` bound a name (each entry of a tuple of
    names); ``optional``: None is allowed too.  ``validate`` checks it, and the
    ROS descriptors, config/online_em_slam.yaml and the offline params-file
    reader are derived from it (parameters/specs.py).
    """

    doc: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    optional: bool = False

    def interval(self) -> str:
        """'(0.0, 100.0]': the allowed range as in the error messages."""
        return f"{'(' if self.lo_open else '['}{self.lo}, {self.hi}{')' if self.hi_open else ']'}"

    def check(self, name: str, value: Any) -> None:
        """ValueError naming ``name`` and the allowed range or choices if ``value`` is outside."""
        if value is None and self.optional:
            return
        if self.choices is not None:
            check_choice(name, value, self.choices)
        elif self.lo is not None:
            check_range(name, value, self.lo, self.hi, self.lo_open, self.hi_open)


def param(default: Any, lo: float | None = None, hi: float | None = None, *, doc: str,
          lo_open: bool = False, hi_open: bool = False, choices: tuple[str, ...] | None = None,
          optional: bool = False) -> Any:
    """A dataclass field with its :class:`ParamInfo` in the metadata (key ``"param"``)."""
    info = ParamInfo(doc, lo, hi, lo_open, hi_open, choices, optional)
    return field(default=default, metadata={"param": info})


def param_info(f: Field) -> ParamInfo:
    return f.metadata["param"]


def check_fields(section: Any, prefix: str, tighter: dict[str, dict[str, Any]] | None = None) -> None:
    """Every field of ``section`` against its ParamInfo, in field order; a tuple
    field entry by entry (its length is checked before, by the section).

    ``tighter``: field name -> ParamInfo changes, a range narrowed by another
    field (one declared, so checked, before it), so the message names the real bound.
    """
    for f in fields(section):
        info = replace(param_info(f), **(tighter or {}).get(f.name, {}))
        value = getattr(section, f.name)
        for entry in value if isinstance(f.default, tuple) else (value,):
            info.check(f"{prefix}.{f.name}", entry)


def check_range(name: str, value: float, low: float, high: float,
                 low_open: bool = False, high_open: bool = False, bound: str = "") -> None:
    """``value`` a finite number within the range; ``bound`` (appended to the error) says what
    sets a range that depends on other parameters."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    ok = (math.isfinite(number) and (number > low if low_open else number >= low)
          and (number < high if high_open else number <= high))
    if not ok:
        brackets = ("(" if low_open else "[", ")" if high_open else "]")
        raise ValueError(f"{name} = {value!r} is outside the allowed range {brackets[0]}{low}, {high}{brackets[1]}"
                         + (f": {bound}" if bound else ""))


def check_length(name: str, value: Any, length: int | None = None, meaning: str = "") -> tuple:
    """``value`` as a tuple of ``length`` entries (any non-zero length if None).

    A scalar or a wrong-length list is refused rather than broadcast: numpy would
    silently spread [1.0] over x, y and yaw, and [1.0, 1.0] fails only at the next
    reset, long after the parameter was accepted.
    """
    try:
        entries = tuple(value)
    except TypeError:
        entries = None
    if entries is None or (len(entries) != length if length is not None else not entries):
        expected = f"exactly {length} numbers" if length is not None else "at least one number"
        raise ValueError(f"{name} = {value!r} must be a list of {expected}{meaning}")
    return entries


def check_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"{name} = {value!r} is not one of {', '.join(choices)}")
