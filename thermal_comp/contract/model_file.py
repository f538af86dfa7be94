"""Read, check and write ``model.json`` (docs/model-json.md): the one validator of model files.

Every rule a model file must meet is reached from here, in one place: ``check_model`` checks
the whole file, with the field rules in ``model_checker``, one axis's in ``model_axis``, the
typed view in ``model_spec``, the hash in ``model_hash`` and the writing in ``json_text`` and
``atomic_file`` (their names are re-exported here for the callers).

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

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from thermal_comp.contract.atomic_file import current_umask, write_text_atomic
from thermal_comp.contract.box import (
    BOX_AUX,
    BOX_AXES,
    BOX_CHANNELS,
    BOX_STATES,
    CHANNEL_MAX_C,
    CHANNEL_MIN_C,
)
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.json_text import dumps, jsonable
from thermal_comp.contract.model_axis import OUTPUT_LIMIT_UM, check_axis
from thermal_comp.contract.model_checker import NAME_RE, Checker
from thermal_comp.contract.model_errors import ModelFormatError, ModelHashError
from thermal_comp.contract.model_hash import check_model_hash, model_hash, stored_hashes
from thermal_comp.contract.model_spec import (
    AuxSpec,
    AxisSpec,
    ChannelSpec,
    ModelSpec,
    ReferenceSpec,
    ServiceSpec,
)
from thermal_comp.contract.terms import TC_TYPES, filter_states
from thermal_comp.contract.textfile import read_utf8
from thermal_comp.contract.tilt import Tilt

__all__ = [  # the model file's API, wherever each part lives
    "NAME_RE", "OUTPUT_LIMIT_UM", "REFERENCE_KINDS", "SCHEMA", "AuxSpec", "AxisSpec",
    "ChannelSpec", "ModelFormatError", "ModelHashError", "ModelSpec", "ReferenceSpec",
    "ServiceSpec", "channel_ranges", "check_model", "check_model_hash", "current_umask", "dumps",
    "jsonable", "model_aux", "model_hash", "model_sensors", "read_model", "read_model_spec",
    "spec_of", "stored_hashes", "write_model", "write_text_atomic",
]

SCHEMA = "thermal-model/1"


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
    """Read, check (structure and stored hash) and return a model file as a dict (its report
    fields too: metrics, training, ...; readers of the function use ``read_model_spec``)."""
    return _read(path)[0]


def read_model_spec(path: str | Path) -> ModelSpec:
    """Read and check a model file as ``read_model`` does; return its function, typed."""
    return _read(path)[1]


def spec_of(model: Mapping | ModelSpec, where: str = "model") -> ModelSpec:
    """The typed view of a model: itself when already typed, else ``check_model``'s (a reader
    handed the dict at the edge types it once; the float output-range check is codegen's)."""
    if isinstance(model, ModelSpec):
        return model
    return check_model(model, where, output_range=False)


def _read(path: str | Path) -> tuple[dict, ModelSpec]:
    path = Path(path)
    if not path.is_file():
        raise ModelFormatError(f"{path}: model file not found")
    text = read_utf8(path)
    try:
        model = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{path}, line {exc.lineno}, column {exc.colno}: not valid JSON "
                               f"({exc.msg})") from None
    spec = check_model(model, str(path))
    check_model_hash(model, str(path))
    return model, spec


def check_model(model: Any, where: str = "model", *, output_range: bool = True) -> ModelSpec:
    """Raise ModelFormatError unless ``model`` is a model the box can run; return its typed view.

    ``where`` (a path) prefixes every message; each message then names the key
    (``channels[2].max_c``, ``axis 'dz_um' term 1 lag(T05, tau=1800s): alpha``) and the limit.
    ``output_range=False`` skips the float output-range check (codegen does it exactly). The
    stored hash is checked by ``read_model`` / ``check_model_hash``, not here.
    """
    c = Checker(where)
    if not isinstance(model, Mapping):
        c.fail("top level is not a JSON object")
    if model.get("schema") != SCHEMA:
        c.fail(f"schema {model.get('schema')!r} is not supported (expected {SCHEMA!r})")
    period = c.number(model.get("sample_period_s"), "sample_period_s")
    if not period > 0:
        c.fail(f"sample_period_s must be a positive number of seconds (got {period!r})")

    channels = _check_channels(c, model)
    aux = _check_aux(c, model, [ch.sensor for ch in channels])

    time_max_s = model.get("time_max_s")
    if time_max_s is not None:
        time_max_s = c.number(time_max_s, "time_max_s")
        if time_max_s < 0:
            c.fail(f"time_max_s: {time_max_s!r} s must not be negative")

    reference = _check_reference(c, model.get("reference"))

    axes = _check_axes(c, model.get("axes"), channels, aux, time_max_s, output_range)
    tilts = _check_tilts(c, model.get("tilts"), axes)
    states = filter_states(t for ax in axes for t in ax.terms)
    if states > BOX_STATES:
        c.fail(f"the model has {states} distinct lag/rate filters (sensor and time constant); "
               f"the box holds {BOX_STATES} filter states (contract.box.BOX_STATES)")
    return ModelSpec(period, tuple(channels), tuple(aux), time_max_s, tuple(axes),
                     model_hash(model), reference, tilts)


def _check_channels(c: Checker, model: Mapping) -> list[ChannelSpec]:
    """``channels``: wired sensors, thermocouple types, valid and training ranges, limits."""
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
        step = c.step_limit(ch, key, sensor, "max_step_c", "degC")
        still = c.still_limit(ch, key, sensor)
        channels.append(ChannelSpec(ch["channel"], sensor, tc, lo, hi, t_lo, t_hi, step, still))
    sensors = [ch.sensor for ch in channels]
    if len(set(sensors)) != len(sensors):
        c.fail(f"channels: sensor names must be unique (got {', '.join(sensors)})")
    return channels


def _check_aux(c: Checker, model: Mapping, sensors: list[str]) -> list[AuxSpec]:
    """``aux``: the auxiliary inputs, named apart from the sensors, with their ranges."""
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
    return aux


def _check_axes(c: Checker, axes_raw: object, channels: list[ChannelSpec], aux: list[AuxSpec],
                time_max_s: float | None, output_range: bool) -> list[AxisSpec]:
    """``axes``: at least one, at most the box's, each checked by ``model_axis.check_axis``."""
    if not isinstance(axes_raw, Mapping) or not axes_raw:
        c.fail("axes: the model has no axes (expected a non-empty object)")
    if len(axes_raw) > BOX_AXES:
        c.fail(f"axes: {len(axes_raw)} axes, the box has {BOX_AXES} (contract.box.BOX_AXES, "
               "BOX_MAX_AXES in box_config.h); the firmware would not build")
    return [check_axis(c, name, ax, channels, aux, time_max_s, output_range)
            for name, ax in axes_raw.items()]


REFERENCE_KINDS = ("start", "none")


def _check_tilts(c: Checker, raw: object, axes: list[AxisSpec]) -> tuple[Tilt, ...]:
    """``tilts`` (docs/model-json.md): how each µrad axis is computed from two gap probes."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        c.fail(f"tilts: expected a list of {{name, upper, lower, distance_mm}}, got {raw!r}")
    units = {ax.name: ax.unit for ax in axes}
    tilts = []
    for i, entry in enumerate(raw):
        try:
            tilt = Tilt.from_json(entry)
        except InputError as exc:
            c.fail(f"tilts[{i}]: {exc}")
        except (KeyError, TypeError, ValueError) as exc:
            c.fail(f"tilts[{i}]: expected {{name, upper, lower, distance_mm}} ({exc})")
        if units.get(tilt.name) != "urad":
            c.fail(f"tilts[{i}]: '{tilt.name}' is not an axis in urad of this model")
        tilts.append(tilt)
    return tuple(tilts)


def _check_reference(c: Checker, ref: object) -> ReferenceSpec:
    """``reference`` (docs/model-json.md): absent/null (none), or {kind, samples}."""
    if ref is None:
        return ReferenceSpec()
    if not isinstance(ref, Mapping):
        c.fail(f"reference: expected an object such as {{\"kind\": \"start\", \"samples\": 8}}, "
               f"got {ref!r}")
    kind = ref.get("kind")
    if kind not in REFERENCE_KINDS:
        c.fail(f"reference.kind: {kind!r} is not one of {', '.join(REFERENCE_KINDS)}")
    samples = ref.get("samples", 1)
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        c.fail(f"reference.samples: expected a whole number of samples >= 1, got {samples!r}")
    return ReferenceSpec(kind, samples)


def model_sensors(model: Mapping | ModelSpec) -> list[str]:
    """Sensors wired to the box, in channel order."""
    return spec_of(model).sensors


def channel_ranges(model: Mapping | ModelSpec) -> dict[str, tuple[float, float]]:
    """Each wired sensor's valid range (min_c, max_c) in degC, defaults filled in."""
    return {c.sensor: (c.min_c, c.max_c) for c in spec_of(model).channels}


def model_aux(model: Mapping | ModelSpec) -> list[str]:
    """Aux inputs, in input order."""
    return spec_of(model).aux_names
