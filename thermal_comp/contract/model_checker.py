"""The field rules of model.json: numbers, names, indexed lists, limits and training ranges.

One checker raises every refusal with the file and the key in front, so all of the model's
parts (channels, aux inputs, axes, terms) are refused in the same words.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import NoReturn

from thermal_comp.contract.box import MAX_STILL_SAMPLES, MIN_STILL_SAMPLES
from thermal_comp.contract.model_errors import ModelFormatError

# Names end up in C string literals, comments and the wire protocol's INFO line
# (separators , ; : *), so they are restricted to characters safe in all three.
NAME_CHARS = "A-Za-z0-9_.+-"  # a regex character class's contents
NAME_RE = re.compile(rf"^[{NAME_CHARS}]{{1,32}}$")


def is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


class Checker:
    """The rules every field of a model file meets, each failing with the key it names."""

    def __init__(self, where: str) -> None:
        self.prefix = f"{where}: " if where else ""

    def fail(self, msg: str) -> NoReturn:
        raise ModelFormatError(self.prefix + msg)

    def number(self, value: object, key: str) -> float:
        if not is_number(value):
            self.fail(f"{key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            self.fail(f"{key}: expected a finite number, got {value!r}")
        return float(value)

    def name(self, value: object, key: str) -> str:
        if not isinstance(value, str) or not NAME_RE.match(value):
            self.fail(f"{key}: name {value!r} must be 1-32 characters of "
                      "A-Z a-z 0-9 _ . + - (it goes into C strings and the INFO line)")
        return value

    def entries(self, model: Mapping, key: str, index: str, limit: int, limit_name: str,
                what: str, required: bool) -> list[Mapping]:
        raw = model.get(key) if required or key in model else []
        if not isinstance(raw, list):
            self.fail(f"'{key}' must be a list (got {type(raw).__name__})")
        if len(raw) > limit:
            self.fail(f"{key}: {len(raw)} {what}, the box has {limit} ({limit_name}); the "
                      "firmware would not build")
        indices = []
        for i, item in enumerate(raw):
            if not isinstance(item, Mapping):
                self.fail(f"{key}[{i}]: expected an object, got {item!r}")
            v = item.get(index)
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(f"{key}[{i}].{index}: expected an integer index, got {v!r}")
            indices.append(v)
        if sorted(indices) != list(range(len(raw))):
            self.fail(f"{key}: the {index} indices must be 0..{len(raw) - 1} "
                      f"(one per entry), got {sorted(indices)}")
        return [raw[indices.index(i)] for i in range(len(raw))]

    def step_limit(self, e: Mapping, where: str, label: str, key: str, unit: str
                   ) -> float | None:
        """An optional step limit: a positive finite number when present."""
        if key not in e:
            return None  # a model written before the step limits were kept
        v = self.number(e[key], f"{where}.{key}")
        if not v > 0:
            self.fail(f"{where}.{key} ({label}): {v!r} {unit} per sample must be positive (the "
                      "largest change the box accepts per sample)")
        return v

    def still_limit(self, e: Mapping, where: str, label: str) -> int | None:
        """The optional stuck limit: a whole number of samples the box's uint16_t holds."""
        key = "max_still_samples"
        if key not in e:
            return None  # a model written before the stuck check: the box has none for it
        v = e[key]
        if isinstance(v, bool) or not isinstance(v, int) \
                or not MIN_STILL_SAMPLES <= v <= MAX_STILL_SAMPLES:
            self.fail(f"{where}.{key} ({label}): {v!r} must be a whole number of samples from "
                      f"{MIN_STILL_SAMPLES} to {MAX_STILL_SAMPLES} (the box faults the channel "
                      "as STUCK when its code stays the same that many samples in a row)")
        return v

    def trained(self, e: Mapping, where: str, label: str, keys: tuple[str, str]
                ) -> tuple[float | None, float | None]:
        if not any(k in e for k in keys):
            return None, None  # a model written before training ranges were kept
        lo, hi = (e.get(k) for k in keys)
        for k, v in zip(keys, (lo, hi), strict=True):
            if not is_number(v) or not math.isfinite(v):
                self.fail(f"{where}.{k} ({label}): {keys[0]} and {keys[1]} must both be finite "
                          f"numbers (got {lo!r}, {hi!r})")
        if lo > hi:
            self.fail(f"{where} ({label}): training range {lo:g}..{hi:g} is empty "
                      f"({keys[0]} > {keys[1]})")
        return float(lo), float(hi)
