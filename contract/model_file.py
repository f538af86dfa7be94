"""Read and write ``model.json`` (docs/model-json.md): atomic writes, checked reads.

The one reader and validator of model files: every command and codegen read a model through
``read_model`` / ``check_model`` here.

A model file is replaced in one step (temp file in the same directory, then rename) so a crash
or a codegen run never sees half a file. JSON has no NaN or infinity: such metric values are
written as ``null``.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from contract.errors import InputError
from contract.terms import AUX_KINDS, TEMPERATURE_KINDS, Term

SCHEMA = "thermal-model/1"


class ModelFormatError(InputError):
    """A model file is missing, not JSON, or breaks the schema; the message names where."""


def jsonable(value: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python (duck-typed, no numpy import), non-finite
    floats to None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return jsonable(value.tolist())  # numpy arrays and scalars
    if isinstance(value, bool) or value is None or isinstance(value, (str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return value


def dumps(model: dict) -> str:
    return json.dumps(jsonable(model), indent=2, allow_nan=False) + "\n"


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write a text file in one step: temp file beside it, fsync, rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_model(model: dict, path: str | Path) -> None:
    """Check the model and write it atomically (nothing is written if it is invalid)."""
    text = dumps(model)
    check_model(json.loads(text), str(path))
    write_text_atomic(path, text)


def read_model(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ModelFormatError(f"{path}: model file not found")
    try:
        model = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{path}, line {exc.lineno}, column {exc.colno}: not valid JSON "
                               f"({exc.msg})") from None
    check_model(model, str(path))
    return model


def check_model(model: Any, where: str = "model") -> None:
    """Raise ModelFormatError unless ``model`` has the schema's required structure."""
    def fail(msg: str) -> None:
        raise ModelFormatError(f"{where}: {msg}")

    if not isinstance(model, dict):
        fail("top level is not a JSON object")
    if model.get("schema") != SCHEMA:
        fail(f"schema is {model.get('schema')!r}, expected {SCHEMA!r}")
    period = model.get("sample_period_s")
    if not isinstance(period, (int, float)) or not period > 0:
        fail(f"sample_period_s must be a positive number (got {period!r})")
    channels = model.get("channels")
    aux = model.get("aux", [])
    axes = model.get("axes")
    if not isinstance(channels, list) or not isinstance(aux, list):
        fail("'channels' and 'aux' must be lists")
    if not isinstance(axes, dict) or not axes:
        fail("'axes' must be a non-empty object")
    sensors = [c.get("sensor") for c in channels]
    indices = [c.get("channel") for c in channels]
    if len(set(sensors)) != len(sensors) or len(set(indices)) != len(indices):
        fail("channels: duplicate sensor or channel index")
    aux_names = [a.get("name") for a in aux]
    for kind, entries, keys in (("channels", channels, ("trained_min_c", "trained_max_c")),
                                ("aux", aux, ("trained_min", "trained_max"))):
        for e in entries:
            if not any(k in e for k in keys):
                continue  # a model written before training ranges were kept
            lo, hi = (e.get(k) for k in keys)
            label = e.get("sensor", e.get("name"))
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and
                       math.isfinite(v) for v in (lo, hi)):
                fail(f"{kind} '{label}': {keys[0]} and {keys[1]} must both be finite numbers "
                     f"(got {lo!r}, {hi!r})")
            if lo > hi:
                fail(f"{kind} '{label}': training range {lo:g}..{hi:g} is empty "
                     f"({keys[0]} > {keys[1]})")
    for name, axis in axes.items():
        if not isinstance(axis, dict):
            fail(f"axis '{name}' is not an object")
        if not isinstance(axis.get("intercept"), (int, float)):
            fail(f"axis '{name}': intercept missing or not a number")
        terms = axis.get("terms")
        if not isinstance(terms, list):
            fail(f"axis '{name}': 'terms' must be a list")
        for j, t in enumerate(terms):
            if not isinstance(t, dict) or not isinstance(t.get("coef"), (int, float)):
                fail(f"axis '{name}', term {j}: needs a numeric 'coef'")
            try:
                term = Term.from_json(t)
            except (ValueError, KeyError, TypeError) as exc:
                fail(f"axis '{name}', term {j}: {exc}")
            if term.kind in TEMPERATURE_KINDS and term.source not in sensors:
                fail(f"axis '{name}', term {j} ({term.name}): sensor '{term.source}' is not in "
                     "'channels'")
            if term.kind in AUX_KINDS and term.source not in aux_names:
                fail(f"axis '{name}', term {j} ({term.name}): input '{term.source}' is not in "
                     "'aux'")


def model_sensors(model: dict) -> list[str]:
    """Sensors wired to the box, in channel order."""
    return [c["sensor"] for c in sorted(model["channels"], key=lambda c: c["channel"])]


def model_aux(model: dict) -> list[str]:
    return [a["name"] for a in sorted(model.get("aux", []), key=lambda a: a["input"])]
