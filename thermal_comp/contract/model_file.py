"""Read, check and write ``model.json`` (docs/model-json.md): the one validator of model files.

Over 400 lines on purpose: every rule a model file must meet lives here, in one place.

Every command and codegen read a model through ``read_model`` (a file) or ``check_model`` (a
dict): the same structural rules everywhere, so ``host evaluate`` cannot accept a model that
``host codegen`` refuses. The rules need no quantisation (codegen adds only what does: whole
milliseconds, multiples of 2^-30, the 19-bit code range, the exact accumulator bound):

- schema ``thermal-model/1``; ``sample_period_s`` a positive finite number;
- names (sensors, aux inputs, axes) 1-32 characters of ``A-Z a-z 0-9 _ . + -``, unique;
- channel indices exactly 0..n-1, at most ``contract.box.BOX_CHANNELS`` channels (likewise aux
  inputs and ``BOX_AUX``, axes and ``BOX_AXES``, filter states and ``BOX_STATES``), thermocouple
  types the box linearises, valid and training ranges that are finite and not empty;
- every number a finite JSON number (``true`` is not a coefficient), alpha in (0, 1], tau > 0;
  each term's source wired (a channel or an aux input), a ``time`` term only with ``time_max_s``;
- (``output_range``) each axis's output over the declared input ranges fits the box's int32
  nanometres (a 1e30 coefficient is refused here, not printed as 1e31 um);
- (files) the content still matches its stored hash (``model_hash``, and
  ``fixed_point.model_hash`` when codegen's block is present): a model edited after
  ``host train`` wrote it is refused, naming both hashes.

A model file is replaced in one step (temp file in the same directory, then rename) so a crash
or a codegen run never sees half a file. JSON has no NaN or infinity: such metric values are
written as ``null``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from thermal_comp.contract.box import (
    BOX_AUX,
    BOX_AXES,
    BOX_CHANNELS,
    BOX_STATES,
    CHANNEL_MAX_C,
    CHANNEL_MIN_C,
    MAX_STILL_SAMPLES,
    MIN_STILL_SAMPLES,
    RUNTIME_MAX_TERMS_PER_AXIS,
)
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.fixed_point import INT32_MAX
from thermal_comp.contract.service import SERVICE_FIELDS, SERVICE_OPTIONAL, service_value_problem
from thermal_comp.contract.terms import (
    AUX_KINDS,
    FILTER_KINDS,
    KINDS,
    TC_TYPES,
    TEMPERATURE_KINDS,
    Term,
    filter_states,
)
from thermal_comp.contract.textfile import read_utf8
from thermal_comp.contract.tilt import AXIS_UNITS, Tilt, unit_of

SCHEMA = "thermal-model/1"
# Names end up in C string literals, comments and the wire protocol's INFO line
# (separators , ; : *), so they are restricted to characters safe in all three.
NAME_RE = re.compile(r"^[A-Za-z0-9_.+-]{1,32}$")
OUTPUT_LIMIT_UM = INT32_MAX / 1000  # the box's output is int32 nanometres


class ModelFormatError(InputError):
    """A model file is missing, not JSON, or breaks the schema; the message names where."""


class ModelHashError(ModelFormatError):
    """A model's content no longer matches the hash stored with it (edited or corrupted)."""


# ---- the model hash ------------------------------------------------------------------------

def _service_core(block: object) -> object:
    """The fields of an axis's ``service`` block that change the box (not its ``why``)."""
    if not isinstance(block, Mapping):
        return block
    return {k: block[k] for k in SERVICE_FIELDS if k in block}


def model_hash(model: Mapping) -> str:
    """First 16 hex digits of SHA-256 over the canonical JSON of the model's function.

    Canonical = sorted keys, no spaces, of ``{sample_period_s, channels, aux, time_max_s,
    axes: {name: {unit, intercept, terms[, max_step_um]}}}`` (docs/model-json.md); metrics,
    selection traces, the stored ``model_hash`` and the ``fixed_point`` block do not change it.
    A missing optional key hashes as ``null`` (``aux`` as ``[]``; ``max_step_um``, the box's
    output step limit, is left out when absent so that older models keep their hash). The
    top-level ``reference`` (what zero means; a ``start`` model's box zeroes at power-up) is
    part of the function too, and likewise left out when absent. So is an axis's ``service``
    block (issue 42: its parameters are in the header and decide what the box does with a
    probe reading), its numeric fields only (``why`` is an explanation), left out when absent.
    """
    core = {
        "sample_period_s": model.get("sample_period_s"),
        "channels": model.get("channels", []),
        "aux": model.get("aux", []),
        "time_max_s": model.get("time_max_s"),
        "axes": {
            name: {"unit": ax.get("unit"), "intercept": ax.get("intercept"),
                   "terms": ax.get("terms", []),
                   **({"max_step_um": ax["max_step_um"]} if "max_step_um" in ax else {}),
                   **({"service": _service_core(ax["service"])} if "service" in ax else {})}
            for name, ax in model.get("axes", {}).items()
        },
    }
    if "reference" in model:
        core["reference"] = model["reference"]
    text = json.dumps(core, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def stored_hashes(model: Mapping) -> dict[str, str]:
    """The hashes a model carries, by key: ``model_hash`` and ``fixed_point.model_hash``."""
    out = {}
    if "model_hash" in model:
        out["model_hash"] = model["model_hash"]
    fp = model.get("fixed_point")
    if isinstance(fp, Mapping) and "model_hash" in fp:
        out["fixed_point.model_hash"] = fp["model_hash"]
    return out


def check_model_hash(model: Mapping, where: str = "model") -> str:
    """The model's hash; ModelHashError when a stored hash differs from the content's."""
    actual = model_hash(model)
    for key, stored in stored_hashes(model).items():
        if stored != actual:
            raise ModelHashError(
                f"{where}: {key}: the stored hash {stored!r} does not match the model's content "
                f"(hash {actual!r}): its coefficients, terms, channels or ranges were changed "
                "after it was written. Train it again; if the edit is deliberate, delete "
                "'model_hash' and the 'fixed_point' block (docs/model-json.md)")
    return actual


# ---- JSON helpers --------------------------------------------------------------------------

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


def current_umask() -> int:
    """The process's umask (read from /proc where it can be, without changing it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write a text file in one step: temp file beside it, fsync, rename.

    The file gets the mode any tool gives a new file (0o666 less the umask), not mkstemp's
    0600: the LinuxCNC user or a colleague must be able to read a model.json or model.h."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_model(model: dict, path: str | Path) -> None:
    """Check the model, stamp its hash (``model_hash``) and write it atomically.

    Nothing is written if it is invalid, or if it carries a ``fixed_point`` block made for
    other content. ``model`` itself gets the ``model_hash`` key too.
    """
    doc = json.loads(dumps(model))
    doc.pop("model_hash", None)
    check_model(doc, f"{path} (not written)")  # a refusal must not name it as if it existed
    doc["model_hash"] = model_hash(doc)
    check_model_hash(doc, str(path))
    write_text_atomic(path, dumps(doc))
    model["model_hash"] = doc["model_hash"]


def read_model(path: str | Path) -> dict:
    """Read, check (structure and stored hash) and return a model file as a dict."""
    path = Path(path)
    if not path.is_file():
        raise ModelFormatError(f"{path}: model file not found")
    text = read_utf8(path)
    try:
        model = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{path}, line {exc.lineno}, column {exc.colno}: not valid JSON "
                               f"({exc.msg})") from None
    check_model(model, str(path))
    check_model_hash(model, str(path))
    return model


# ---- the typed view ------------------------------------------------------------------------

@dataclass(frozen=True)
class ChannelSpec:
    channel: int
    sensor: str
    tc_type: str
    min_c: float
    max_c: float
    trained_min_c: float | None
    trained_max_c: float | None


@dataclass(frozen=True)
class AuxSpec:
    input: int
    name: str
    min: float
    max: float
    trained_min: float | None
    trained_max: float | None


@dataclass(frozen=True)
class AxisSpec:
    name: str
    unit: str
    intercept: float
    terms: tuple[Term, ...]
    coefs: tuple[float, ...]


@dataclass(frozen=True)
class ModelSpec:
    """A checked model's function, typed (the dict stays the file's full content)."""

    sample_period_s: float
    channels: tuple[ChannelSpec, ...]  # in channel order
    aux: tuple[AuxSpec, ...]  # in input order
    time_max_s: float | None
    axes: tuple[AxisSpec, ...]
    model_hash: str

    @property
    def sensors(self) -> list[str]:
        return [c.sensor for c in self.channels]

    @property
    def aux_names(self) -> list[str]:
        return [a.name for a in self.aux]

    def channel(self, sensor: str) -> ChannelSpec:
        return next(c for c in self.channels if c.sensor == sensor)


# ---- the checks ----------------------------------------------------------------------------

def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _term_label(kind: object, source: object, t: Mapping) -> str:
    tau, ref = t.get("tau_s"), t.get("ref_c")
    if kind in FILTER_KINDS and _is_number(tau) and math.isfinite(tau):
        return f"{kind}({source}, tau={tau:g}s)"
    if kind == "square" and _is_number(ref) and math.isfinite(ref):
        return f"square({source}-{ref:g}C)"
    if kind == "time":
        return "time"
    return f"{kind}({source})"


class _Checker:
    def __init__(self, where: str) -> None:
        self.prefix = f"{where}: " if where else ""

    def fail(self, msg: str) -> NoReturn:
        raise ModelFormatError(self.prefix + msg)

    def number(self, value: object, key: str) -> float:
        if not _is_number(value):
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

    def step_limit(self, e: Mapping, where: str, label: str, key: str, unit: str) -> None:
        """An optional step limit: a positive finite number when present."""
        if key not in e:
            return  # a model written before the step limits were kept
        v = self.number(e[key], f"{where}.{key}")
        if not v > 0:
            self.fail(f"{where}.{key} ({label}): {v!r} {unit} per sample must be positive (the "
                      "largest change the box accepts per sample)")

    def still_limit(self, e: Mapping, where: str, label: str) -> None:
        """The optional stuck limit: a whole number of samples the box's uint16_t holds."""
        key = "max_still_samples"
        if key not in e:
            return  # a model written before the stuck check: the box has none for it
        v = e[key]
        if isinstance(v, bool) or not isinstance(v, int) \
                or not MIN_STILL_SAMPLES <= v <= MAX_STILL_SAMPLES:
            self.fail(f"{where}.{key} ({label}): {v!r} must be a whole number of samples from "
                      f"{MIN_STILL_SAMPLES} to {MAX_STILL_SAMPLES} (the box faults the channel "
                      "as STUCK when its code stays the same that many samples in a row)")

    def trained(self, e: Mapping, where: str, label: str, keys: tuple[str, str]
                ) -> tuple[float | None, float | None]:
        if not any(k in e for k in keys):
            return None, None  # a model written before training ranges were kept
        lo, hi = (e.get(k) for k in keys)
        for k, v in zip(keys, (lo, hi), strict=True):
            if not _is_number(v) or not math.isfinite(v):
                self.fail(f"{where}.{k} ({label}): {keys[0]} and {keys[1]} must both be finite "
                          f"numbers (got {lo!r}, {hi!r})")
        if lo > hi:
            self.fail(f"{where} ({label}): training range {lo:g}..{hi:g} is empty "
                      f"({keys[0]} > {keys[1]})")
        return float(lo), float(hi)


def check_model(model: Any, where: str = "model", *, output_range: bool = True) -> ModelSpec:
    """Raise ModelFormatError unless ``model`` is a model the box can run; return its typed view.

    ``where`` (a path) prefixes every message; each message then names the key
    (``channels[2].max_c``, ``axis 'dz_um' term 1 lag(T05, tau=1800s): alpha``) and the limit.
    ``output_range=False`` skips the float output-range check (codegen does it exactly). The
    stored hash is checked by ``read_model`` / ``check_model_hash``, not here.
    """
    c = _Checker(where)
    if not isinstance(model, Mapping):
        c.fail("top level is not a JSON object")
    if model.get("schema") != SCHEMA:
        c.fail(f"schema {model.get('schema')!r} is not supported (expected {SCHEMA!r})")
    period = c.number(model.get("sample_period_s"), "sample_period_s")
    if not period > 0:
        c.fail(f"sample_period_s must be a positive number of seconds (got {period!r})")

    channels = []
    for ch in c.entries(model, "channels", "channel", BOX_CHANNELS,
                        "contract.box.BOX_CHANNELS, BOX_MAX_CHANNELS in box_config.h",
                        "channels", required=True):
        key = f"channels[{ch['channel']}]"
        sensor = c.name(ch.get("sensor"), f"{key}.sensor")
        tc = ch.get("tc_type", "K")
        if not isinstance(tc, str) or tc not in TC_TYPES:
            c.fail(f"{key} ({sensor}): thermocouple type {tc!r} is not supported "
                   f"(known: {', '.join(TC_TYPES)})")
        lo = c.number(ch.get("min_c", CHANNEL_MIN_C), f"{key}.min_c")
        hi = c.number(ch.get("max_c", CHANNEL_MAX_C), f"{key}.max_c")
        if lo >= hi:
            c.fail(f"{key} ({sensor}): valid range {lo:g}..{hi:g} degC is empty "
                   "(min_c must be below max_c)")
        t_lo, t_hi = c.trained(ch, key, sensor, ("trained_min_c", "trained_max_c"))
        c.step_limit(ch, key, sensor, "max_step_c", "degC")
        c.still_limit(ch, key, sensor)
        channels.append(ChannelSpec(ch["channel"], sensor, tc, lo, hi, t_lo, t_hi))
    sensors = [ch.sensor for ch in channels]
    if len(set(sensors)) != len(sensors):
        c.fail(f"channels: sensor names must be unique (got {', '.join(sensors)})")

    aux = []
    for a in c.entries(model, "aux", "input", BOX_AUX,
                       "contract.box.BOX_AUX, BOX_MAX_AUX in box_config.h", "auxiliary inputs",
                       required=False):
        key = f"aux[{a['input']}]"
        name = c.name(a.get("name"), f"{key}.name")
        lo = c.number(a.get("min"), f"{key}.min")
        hi = c.number(a.get("max"), f"{key}.max")
        if lo > hi:
            c.fail(f"{key} ({name}): range {lo:g}..{hi:g} is empty (min > max)")
        t_lo, t_hi = c.trained(a, key, name, ("trained_min", "trained_max"))
        aux.append(AuxSpec(a["input"], name, lo, hi, t_lo, t_hi))
    aux_names = [a.name for a in aux]
    if len(set(aux_names)) != len(aux_names) or set(aux_names) & set(sensors):
        c.fail(f"aux: names must be unique and differ from the sensors (got "
               f"{', '.join(aux_names)})")

    time_max_s = model.get("time_max_s")
    if time_max_s is not None:
        time_max_s = c.number(time_max_s, "time_max_s")
        if time_max_s < 0:
            c.fail(f"time_max_s: {time_max_s!r} s must not be negative")

    _check_reference(c, model.get("reference"))

    axes_raw = model.get("axes")
    if not isinstance(axes_raw, Mapping) or not axes_raw:
        c.fail("axes: the model has no axes (expected a non-empty object)")
    if len(axes_raw) > BOX_AXES:
        c.fail(f"axes: {len(axes_raw)} axes, the box has {BOX_AXES} (contract.box.BOX_AXES, "
               "BOX_MAX_AXES in box_config.h); the firmware would not build")
    axes = [_check_axis(c, name, ax, channels, aux, time_max_s, output_range)
            for name, ax in axes_raw.items()]
    _check_tilts(c, model.get("tilts"), axes)
    states = filter_states(t for ax in axes for t in ax.terms)
    if states > BOX_STATES:
        c.fail(f"the model has {states} distinct lag/rate filters (sensor and time constant); "
               f"the box holds {BOX_STATES} filter states (contract.box.BOX_STATES)")
    return ModelSpec(period, tuple(channels), tuple(aux), time_max_s, tuple(axes),
                     model_hash(model))


REFERENCE_KINDS = ("start", "none")


def _check_tilts(c: _Checker, raw: object, axes: list[AxisSpec]) -> None:
    """``tilts`` (docs/model-json.md): how each µrad axis is computed from two gap probes."""
    if raw is None:
        return
    if not isinstance(raw, list):
        c.fail(f"tilts: expected a list of {{name, upper, lower, distance_mm}}, got {raw!r}")
    units = {ax.name: ax.unit for ax in axes}
    for i, entry in enumerate(raw):
        try:
            tilt = Tilt.from_json(entry)
        except InputError as exc:
            c.fail(f"tilts[{i}]: {exc}")
        except (KeyError, TypeError, ValueError) as exc:
            c.fail(f"tilts[{i}]: expected {{name, upper, lower, distance_mm}} ({exc})")
        if units.get(tilt.name) != "urad":
            c.fail(f"tilts[{i}]: '{tilt.name}' is not an axis in urad of this model")


def _check_reference(c: _Checker, ref: object) -> None:
    """``reference`` (docs/model-json.md): absent/null (none), or {kind, samples}."""
    if ref is None:
        return
    if not isinstance(ref, Mapping):
        c.fail(f"reference: expected an object such as {{\"kind\": \"start\", \"samples\": 8}}, "
               f"got {ref!r}")
    kind = ref.get("kind")
    if kind not in REFERENCE_KINDS:
        c.fail(f"reference.kind: {kind!r} is not one of {', '.join(REFERENCE_KINDS)}")
    samples = ref.get("samples", 1)
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        c.fail(f"reference.samples: expected a whole number of samples >= 1, got {samples!r}")


def _check_axis(c: _Checker, name: object, ax: object, channels: list[ChannelSpec],
                aux: list[AuxSpec], time_max_s: float | None, output_range: bool) -> AxisSpec:
    name = c.name(name, f"axes.{name}")
    if not isinstance(ax, Mapping):
        c.fail(f"axis '{name}': expected an object")
    unit = ax.get("unit", "um")
    if unit not in AXIS_UNITS:
        c.fail(f"axis '{name}': unit {unit!r} is not supported (one of {', '.join(AXIS_UNITS)})")
    if unit != unit_of(name):
        c.fail(f"axis '{name}': unit {unit!r}, but the name declares {unit_of(name)!r} (a tilt "
               "axis's name ends in '_urad', every other axis is in um)")
    intercept = c.number(ax.get("intercept"), f"axis '{name}': intercept")
    c.step_limit(ax, f"axis '{name}'", name, "max_step_um", unit)
    _check_service(c, name, ax.get("service"))
    raw = ax.get("terms")
    if not isinstance(raw, list):
        c.fail(f"axis '{name}': 'terms' must be a list")
    if len(raw) > RUNTIME_MAX_TERMS_PER_AXIS:
        c.fail(f"axis '{name}': {len(raw)} terms exceed {RUNTIME_MAX_TERMS_PER_AXIS} "
               "(contract.box.RUNTIME_MAX_TERMS_PER_AXIS)")
    by_sensor = {ch.sensor: ch for ch in channels}
    by_aux = {a.name: a for a in aux}
    terms, coefs, reach = [], [], []
    for j, t in enumerate(raw):
        where = f"axis '{name}' term {j}"
        if not isinstance(t, Mapping):
            c.fail(f"{where}: expected an object, got {t!r}")
        kind, source = t.get("kind"), t.get("source")
        if kind not in KINDS:
            c.fail(f"{where}: unknown term kind {kind!r} (known: {', '.join(KINDS)})")
        where = f"{where} {_term_label(kind, source, t)}"
        coef = c.number(t.get("coef"), f"{where}: coef")
        params = {}
        for k, v in t.items():
            if k not in ("kind", "source", "coef"):
                params[k] = c.number(v, f"{where}: {k}")
        if kind in TEMPERATURE_KINDS or kind in AUX_KINDS:
            if not isinstance(source, str):  # {} or [] was a TypeError (unhashable) here
                c.fail(f"{where}: source must be the name of a "
                       f"{'channel' if kind in TEMPERATURE_KINDS else 'aux input'} "
                       f"(a string), got {json.dumps(source)}")
        if kind in TEMPERATURE_KINDS:
            if source not in by_sensor:
                c.fail(f"{where}: source {source!r} is not in 'channels' "
                       f"({', '.join(by_sensor) or 'none'})")
            lo, hi = by_sensor[source].min_c, by_sensor[source].max_c
        elif kind in AUX_KINDS:
            if source not in by_aux:
                c.fail(f"{where}: source {source!r} is not in 'aux' "
                       f"({', '.join(by_aux) or 'none'})")
            lo, hi = by_aux[source].min, by_aux[source].max
        else:  # time
            if source is not None:
                c.fail(f"{where}: a time term has no source (got {source!r})")
            if time_max_s is None:
                c.fail(f"{where}: the model needs time_max_s for a time term")
            lo, hi = 0.0, time_max_s
        if kind in FILTER_KINDS:
            for k in ("tau_s", "alpha"):
                if k not in params:
                    c.fail(f"{where}: a {kind} term needs '{k}'")
            if not params["tau_s"] > 0:
                c.fail(f"{where}: tau_s {params['tau_s']!r} must be positive")
            if not 0 < params["alpha"] <= 1:
                c.fail(f"{where}: alpha {params['alpha']!r} must be in (0, 1] "
                       "(make it with contract.terms.make_lag/make_rate)")
        elif kind == "square" and "ref_c" not in params:
            c.fail(f"{where}: a square term needs 'ref_c'")
        term = Term(kind, source, params)
        terms.append(term)
        coefs.append(coef)
        reach.append((abs(coef) * _feature_reach(kind, lo, hi, params), where, coef))
    if output_range:
        total = abs(intercept) + sum(r for r, _, _ in reach)
        if not total <= OUTPUT_LIMIT_UM * (1 + 1e-9):
            part = ""
            if reach:
                r, where, coef = max(reach, key=lambda x: x[0])
                part = f"; largest part: {where.removeprefix(f'axis {name!r} ')}, coef " \
                       f"{coef!r}, up to {r:.6g} um"
            c.fail(f"axis '{name}': the output can reach {total:.6g} um over the declared "
                   f"input ranges, beyond the box's int32 nanometre limit "
                   f"{OUTPUT_LIMIT_UM:.6g} um{part}")
    return AxisSpec(name, unit, intercept, tuple(terms), tuple(coefs))


def _check_service(c: _Checker, axis: str, block: object) -> None:
    """``axes.<axis>.service`` (docs/service.md): the in-service estimator's parameters, each
    within the range its fixed-point arithmetic is proven for (contract.service)."""
    if block is None:
        return  # a model trained before issue 42: the estimator uses its fallbacks
    where = f"axis '{axis}': service"
    if not isinstance(block, Mapping):
        c.fail(f"{where}: expected an object of {', '.join(SERVICE_FIELDS)}, got {block!r}")
    for key in SERVICE_FIELDS:
        if key not in block and key in SERVICE_OPTIONAL:
            continue
        if key not in block:
            c.fail(f"{where}.{key}: missing (one of {', '.join(SERVICE_FIELDS)})")
        v = c.number(block[key], f"{where}.{key}")
        if problem := service_value_problem(key, v):
            c.fail(f"{where}.{key}: {problem}")
    why = block.get("why", "")
    if not isinstance(why, str):
        c.fail(f"{where}.why: expected text, got {why!r}")


def _feature_reach(kind: str, lo: float, hi: float, params: Mapping[str, float]) -> float:
    """max |feature| over the declared input range [lo, hi] (docs/codegen.md, proof 2)."""
    m = max(abs(lo), abs(hi))
    if kind in ("temp", "lag", "speed", "time"):
        return m
    if kind == "rate":
        return hi - lo
    if kind == "speed2":
        return m * m
    if kind == "square":
        ref = params["ref_c"]
        return max(abs(lo - ref), abs(hi - ref)) ** 2
    raise AssertionError(kind)


def model_sensors(model: dict) -> list[str]:
    """Sensors wired to the box, in channel order."""
    return [c["sensor"] for c in sorted(model["channels"], key=lambda c: c["channel"])]


def channel_ranges(model: Mapping) -> dict[str, tuple[float, float]]:
    """Each wired sensor's valid range (min_c, max_c) in degC, defaults filled in."""
    return {c["sensor"]: (float(c.get("min_c", CHANNEL_MIN_C)),
                          float(c.get("max_c", CHANNEL_MAX_C)))
            for c in model.get("channels", [])}


def model_aux(model: dict) -> list[str]:
    return [a["name"] for a in sorted(model.get("aux", []), key=lambda a: a["input"])]
