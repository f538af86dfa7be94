"""The thermalcomp component's config file (cnc/config/thermalcomp.conf, docs/linuxcnc.md):
which box axis drives which LinuxCNC axis, the port, the expected model and its step limits.

Standard library and the project's stdlib-only contract only, like the component itself.
"""

from __future__ import annotations

import configparser
import math
from dataclasses import dataclass, field
from pathlib import Path

from contract import model_file
from contract.box import DEFAULT_AXIS_STEP_UM_PER_S
from contract.errors import InputError
from contract.tilt import unit_of

UNITS_MM = {"mm": 1.0, "inch": 25.4}
# The box's clamp, BOX_MAX_CORRECTION_NM in firmware/include/box_config.h (checked by
# tests/test_thermalcomp.py): the default of [box] max_abs_um.
DEFAULT_MAX_ABS_UM = 200.0


class ConfigError(ValueError):
    """The component's config file is missing or wrong (names the file, section and key)."""


@dataclass
class AxisMap:
    """One LinuxCNC axis driven by one box axis."""

    letter: str  # LinuxCNC axis letter, lower case (pin names axis.<letter>.eoffset-*)
    box_axis: str  # name in the box's INFO axis list (the model's target, e.g. dz_um)
    sign: int  # +1: LinuxCNC offset = +correction; -1: offset = -correction
    nm_per_count: float  # size of one eoffset count in nanometres
    step_nm: float | None = None  # the model's step limit of this axis per sample line (nm)
    index: int | None = None  # position in the box's sample line (from INFO)
    base: int = 0  # counts added to the box's value: the offset held over a cold box restart
    want: int = 0  # offset the component wants, in counts
    sent: int = 0  # the offset LinuxCNC has been told (counts) since the last resync
    seen: bool = False  # a value from the box has been applied since start
    box_nm: int = 0  # the box's last correction for this axis
    bias_nm: int = 0  # the box's in-service estimate for this axis (its last $M answer)
    innovation_nm: int = 0  # the last reading's innovation (reading - (model + bias))
    p_nm2: int = 0  # the estimate's variance after the last answer


@dataclass
class Config:
    port: str
    baud: int = 115200
    stale_periods: float = 3.0
    period_s: float | None = None  # None: the box's INFO period
    slew_nm_per_s: float = 1000.0
    units_mm: float = 1.0  # machine units in mm (LINEAR_UNITS)
    settle_s: float = 0.05  # wait after machine-on/enable before reading eoffset-request
    poll_s: float = 0.002
    axes: list[AxisMap] = field(default_factory=list)
    model_hash: str | None = None  # the hash the box's INFO must report (None: refuse to drive)
    model_path: Path | None = None  # where model_hash and the step limits came from
    max_abs_um: float = DEFAULT_MAX_ABS_UM  # no offset ever beyond this (the box's clamp)
    resume: bool = True  # after a power cut ask the box to RESUME its kept state (no: ZERO)
    keep_state: bool = True  # SNAP after each sample with a datum; LOAD it back after a cut
    state_file: Path | None = None  # where that block is also kept (survives this process)
    probe_axis: str | None = None  # [probe] axis: the LinuxCNC axis the probe measures
    probe_timeout_s: float = 2.0  # no $M answer within this: TIMEOUT
    probed_includes_offset: bool = True  # LinuxCNC 2.9: #5063 contains the external offset


def load_config(path: str | Path) -> Config:
    """Read the component's config file (INI syntax, see cnc/config/thermalcomp.conf)."""
    path = Path(path)
    parser = configparser.ConfigParser(inline_comment_prefixes=("#", ";"))
    if not parser.read(path):
        raise ConfigError(f"{path}: component config not found or unreadable")

    def get(section: str, key: str, kind: type, default: object = None) -> object:
        if not parser.has_option(section, key):
            if default is None:
                raise ConfigError(f"{path}: [{section}] needs '{key}'")
            return default
        text = parser.get(section, key)
        try:
            return kind(text)
        except ValueError:
            raise ConfigError(f"{path}: [{section}] {key} = {text!r} is not a valid "
                              f"{kind.__name__}") from None

    if not parser.has_section("box"):
        raise ConfigError(f"{path}: no [box] section (port, stale_periods, ...)")
    units = str(get("machine", "units", str, "mm")) if parser.has_section("machine") else "mm"
    if units not in UNITS_MM:
        raise ConfigError(f"{path}: [machine] units = {units!r}: mm or inch")
    period = get("box", "period_s", float, -1.0)
    cfg = Config(port=str(get("box", "port", str)), baud=int(get("box", "baud", int, 115200)),
                 stale_periods=float(get("box", "stale_periods", float, 3.0)),
                 period_s=None if period == -1.0 else float(period),
                 slew_nm_per_s=float(get("box", "slew_nm_per_s", float, 1000.0)),
                 units_mm=UNITS_MM[units],
                 settle_s=float(get("box", "settle_s", float, 0.05)),
                 poll_s=float(get("box", "poll_s", float, 0.002)))
    for name, value, lo in (("stale_periods", cfg.stale_periods, 1.0),
                            ("slew_nm_per_s", cfg.slew_nm_per_s, 1e-9),
                            ("poll_s", cfg.poll_s, 1e-4)):
        if not (math.isfinite(value) and value >= lo):
            raise ConfigError(f"{path}: [box] {name} = {value:g} must be at least {lo:g}")
    if cfg.period_s is not None and not cfg.period_s > 0:
        raise ConfigError(f"{path}: [box] period_s = {cfg.period_s:g} must be positive")
    cfg.max_abs_um = float(get("box", "max_abs_um", float, DEFAULT_MAX_ABS_UM))
    resume = str(get("box", "resume", str, "yes")).strip().lower()
    if resume not in ("yes", "no"):
        raise ConfigError(f"{path}: [box] resume = {resume!r}: yes or no")
    cfg.resume = resume == "yes"
    keep = str(get("box", "keep_state", str, "yes")).strip().lower()
    if keep not in ("yes", "no"):
        raise ConfigError(f"{path}: [box] keep_state = {keep!r}: yes or no")
    cfg.keep_state = keep == "yes"
    if parser.has_option("box", "state_file"):
        kept = Path(parser.get("box", "state_file").strip())
        cfg.state_file = kept if kept.is_absolute() else path.resolve().parent / kept
    if not (math.isfinite(cfg.max_abs_um) and cfg.max_abs_um > 0):
        raise ConfigError(f"{path}: [box] max_abs_um = {cfg.max_abs_um:g} must be positive")
    model: dict | None = None
    if parser.has_option("box", "model"):
        model_path = Path(parser.get("box", "model").strip())
        if not model_path.is_absolute():
            model_path = path.resolve().parent / model_path  # relative to this file
        try:
            model = model_file.read_model(model_path)
        except (InputError, OSError) as exc:
            raise ConfigError(f"{path}: [box] model = {model_path}: {exc}") from None
        cfg.model_path = model_path
        cfg.model_hash = model_file.model_hash(model)
    if parser.has_option("box", "model_hash"):
        given = parser.get("box", "model_hash").strip()
        if not given:
            raise ConfigError(f"{path}: [box] model_hash is empty")
        if cfg.model_hash is not None and given != cfg.model_hash:
            raise ConfigError(f"{path}: [box] model_hash = {given} but the model "
                              f"{cfg.model_path} has hash {cfg.model_hash}: which one is it?")
        cfg.model_hash = given
    for section in parser.sections():
        if not section.startswith("axis."):
            continue
        letter = section[5:].lower()
        if letter not in "xyzabcuvw" or len(letter) != 1:
            raise ConfigError(f"{path}: [{section}]: the axis letter must be one of XYZABCUVW")
        sign_text = str(get(section, "sign", str)).strip()
        if sign_text not in ("+1", "1", "+", "-1", "-"):
            raise ConfigError(f"{path}: [{section}] sign = {sign_text!r}: +1 or -1")
        nm = float(get(section, "nm_per_count", float, 1.0))
        if not (math.isfinite(nm) and nm > 0):
            raise ConfigError(f"{path}: [{section}] nm_per_count = {nm:g} must be positive")
        box_axis = str(get(section, "box_axis", str))
        if unit_of(box_axis) != "um":
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: a tilt axis (urad) "
                              "is not a linear offset; only axes in um drive external offsets")
        given = (float(get(section, "max_step_um", float))
                 if parser.has_option(section, "max_step_um") else None)
        step_nm = axis_step_nm(path, section, box_axis, model, given,
                                cfg.model_hash is not None)
        if step_nm is not None and nm > step_nm:
            raise ConfigError(f"{path}: [{section}] nm_per_count = {nm:g} is larger than the "
                              f"axis's step limit ({step_nm:g} nm per sample): one count "
                              "would already be more than the step limit")
        cfg.axes.append(AxisMap(letter, box_axis,
                                -1 if sign_text.startswith("-") else 1, nm, step_nm))
    if not cfg.axes:
        raise ConfigError(f"{path}: no [axis.<letter>] section: nothing to drive")
    letters = [a.letter for a in cfg.axes]
    if len(set(letters)) != len(letters):
        raise ConfigError(f"{path}: an axis letter appears twice ({', '.join(letters)})")
    if parser.has_section("probe"):
        axis = str(get("probe", "axis", str)).strip().lower()
        if axis not in letters:
            raise ConfigError(f"{path}: [probe] axis = {axis!r}: not one of the driven axes "
                              f"({', '.join(letters)})")
        cfg.probe_axis = axis
        cfg.probe_timeout_s = float(get("probe", "timeout_s", float, 2.0))
        try:
            cfg.probed_includes_offset = parser.getboolean("probe", "probed_includes_offset",
                                                           fallback=True)
        except ValueError:
            raise ConfigError(f"{path}: [probe] probed_includes_offset = "
                              f"{parser.get('probe', 'probed_includes_offset')!r}: yes or "
                              "no") from None
        if not (math.isfinite(cfg.probe_timeout_s) and cfg.probe_timeout_s > 0):
            raise ConfigError(f"{path}: [probe] timeout_s = {cfg.probe_timeout_s:g} must be "
                              "positive")
    return cfg


def axis_step_nm(path: Path, section: str, box_axis: str, model: dict | None,
                  given_um: float | None, need: bool) -> float | None:
    """An axis's step limit per sample line in nm: the model's ``axes.<name>.max_step_um``
    rounded up to nm as codegen does for the box (a model without it: codegen's default, the
    box's walk-back rate x its period), or ``max_step_um`` in the axis section (the smaller
    of the two when both are given). None when neither exists and no hash is expected."""
    if given_um is not None and not (math.isfinite(given_um) and given_um > 0):
        raise ConfigError(f"{path}: [{section}] max_step_um = {given_um:g} must be positive")
    steps = [given_um * 1000.0] if given_um is not None else []
    if model is not None:
        axes = model.get("axes", {})
        if box_axis not in axes:
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: the model has axes "
                              f"{', '.join(axes) or '(none)'}")
        ax = axes[box_axis]
        step_um = ax["max_step_um"] if "max_step_um" in ax else (
            DEFAULT_AXIS_STEP_UM_PER_S * float(model["sample_period_s"]))
        steps.append(float(math.ceil(float(step_um) * 1000.0)))
    if not steps and need:
        raise ConfigError(f"{path}: [{section}] needs 'max_step_um' (the model's "
                          f"axes.{box_axis}.max_step_um) when [box] gives model_hash without "
                          "model = <model.json>")
    return min(steps) if steps else None
