"""The thermalcomp component's config file (cnc/config/thermalcomp.conf, docs/linuxcnc.md):
which box axis drives which LinuxCNC axis, the port, the expected model and its step limits.

Standard library and the project's stdlib-only contract only, like the component itself.
"""

from __future__ import annotations

import configparser
import math
from dataclasses import dataclass, field
from pathlib import Path

from thermal_comp.contract import model_file
from thermal_comp.contract.box import DEFAULT_AXIS_STEP_UM_PER_S
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_spec import ModelSpec
from thermal_comp.contract.tilt import unit_of

UNITS_MM = {"mm": 1.0, "inch": 25.4}
# The box's clamp, BOX_MAX_CORRECTION_NM in firmware/include/box_config.h (checked by
# tests/cnc/test_thermalcomp.py): the default of [box] max_abs_um.
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


class _Ini:
    """The parsed file and its path, for errors that name file, section and key."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.parser = configparser.ConfigParser(inline_comment_prefixes=("#", ";"))
        if not self.parser.read(path):
            raise ConfigError(f"{path}: component config not found or unreadable")

    def has(self, section: str, key: str) -> bool:
        return self.parser.has_option(section, key)

    def fail(self, what: str) -> ConfigError:
        return ConfigError(f"{self.path}: {what}")

    def get(self, section: str, key: str, kind: type, default: object = None) -> object:
        if not self.parser.has_option(section, key):
            if default is None:
                raise self.fail(f"[{section}] needs '{key}'")
            return default
        text = self.parser.get(section, key)
        try:
            return kind(text)
        except ValueError:
            raise self.fail(f"[{section}] {key} = {text!r} is not a valid "
                            f"{kind.__name__}") from None

    def yes_no(self, section: str, key: str, default: str = "yes") -> bool:
        text = str(self.get(section, key, str, default)).strip().lower()
        if text not in ("yes", "no"):
            raise self.fail(f"[{section}] {key} = {text!r}: yes or no")
        return text == "yes"

    def file(self, section: str, key: str) -> Path:
        """A path given in the file: absolute, or relative to the file."""
        given = Path(self.parser.get(section, key).strip())
        return given if given.is_absolute() else self.path.resolve().parent / given


def load_config(path: str | Path) -> Config:
    """Read the component's config file (INI syntax, see cnc/config/thermalcomp.conf)."""
    ini = _Ini(Path(path))
    if not ini.parser.has_section("box"):
        raise ini.fail("no [box] section (port, stale_periods, ...)")
    cfg = _box(ini)
    model = _model(ini, cfg)
    for section in ini.parser.sections():
        if section.startswith("axis."):
            cfg.axes.append(_axis(ini, section, model, cfg.model_hash is not None))
    if not cfg.axes:
        raise ini.fail("no [axis.<letter>] section: nothing to drive")
    letters = [a.letter for a in cfg.axes]
    if len(set(letters)) != len(letters):
        raise ini.fail(f"an axis letter appears twice ({', '.join(letters)})")
    if ini.parser.has_section("probe"):
        _probe(ini, cfg, letters)
    return cfg


def _box(ini: _Ini) -> Config:
    """[box] and [machine]: the port, the clocks, the bounds, what happens after a power cut."""
    get = ini.get
    units = str(get("machine", "units", str, "mm")) if ini.parser.has_section("machine") else "mm"
    if units not in UNITS_MM:
        raise ini.fail(f"[machine] units = {units!r}: mm or inch")
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
            raise ini.fail(f"[box] {name} = {value:g} must be at least {lo:g}")
    if cfg.period_s is not None and not cfg.period_s > 0:
        raise ini.fail(f"[box] period_s = {cfg.period_s:g} must be positive")
    cfg.max_abs_um = float(get("box", "max_abs_um", float, DEFAULT_MAX_ABS_UM))
    cfg.resume = ini.yes_no("box", "resume")
    cfg.keep_state = ini.yes_no("box", "keep_state")
    if ini.has("box", "state_file"):
        cfg.state_file = ini.file("box", "state_file")
    if not (math.isfinite(cfg.max_abs_um) and cfg.max_abs_um > 0):
        raise ini.fail(f"[box] max_abs_um = {cfg.max_abs_um:g} must be positive")
    return cfg


def _model(ini: _Ini, cfg: Config) -> ModelSpec | None:
    """[box] model and/or model_hash: the model the box must carry (its hash into cfg)."""
    model: ModelSpec | None = None
    if ini.has("box", "model"):
        model_path = ini.file("box", "model")
        try:
            model = model_file.read_model_spec(model_path)
        except (InputError, OSError) as exc:
            raise ini.fail(f"[box] model = {model_path}: {exc}") from None
        cfg.model_path = model_path
        cfg.model_hash = model.model_hash
    if ini.has("box", "model_hash"):
        given = ini.parser.get("box", "model_hash").strip()
        if not given:
            raise ini.fail("[box] model_hash is empty")
        if cfg.model_hash is not None and given != cfg.model_hash:
            raise ini.fail(f"[box] model_hash = {given} but the model {cfg.model_path} has "
                           f"hash {cfg.model_hash}: which one is it?")
        cfg.model_hash = given
    return model


def _axis(ini: _Ini, section: str, model: ModelSpec | None, need_step: bool) -> AxisMap:
    """One [axis.<letter>] section: the LinuxCNC axis, its box axis, sign, count and step."""
    path, get = ini.path, ini.get
    letter = section[5:].lower()
    if letter not in "xyzabcuvw" or len(letter) != 1:
        raise ini.fail(f"[{section}]: the axis letter must be one of XYZABCUVW")
    sign_text = str(get(section, "sign", str)).strip()
    if sign_text not in ("+1", "1", "+", "-1", "-"):
        raise ini.fail(f"[{section}] sign = {sign_text!r}: +1 or -1")
    nm = float(get(section, "nm_per_count", float, 1.0))
    if not (math.isfinite(nm) and nm > 0):
        raise ini.fail(f"[{section}] nm_per_count = {nm:g} must be positive")
    box_axis = str(get(section, "box_axis", str))
    if unit_of(box_axis) != "um":
        raise ini.fail(f"[{section}] box_axis = {box_axis}: a tilt axis (urad) is not a linear "
                       "offset; only axes in um drive external offsets")
    given = float(get(section, "max_step_um", float)) if ini.has(section, "max_step_um") else None
    step_nm = axis_step_nm(path, section, box_axis, model, given, need_step)
    if step_nm is not None and nm > step_nm:
        raise ini.fail(f"[{section}] nm_per_count = {nm:g} is larger than the axis's step "
                       f"limit ({step_nm:g} nm per sample): one count would already be more "
                       "than the step limit")
    return AxisMap(letter, box_axis, -1 if sign_text.startswith("-") else 1, nm, step_nm)


def _probe(ini: _Ini, cfg: Config, letters: list[str]) -> None:
    """[probe]: the axis the touch probe measures, its answer timeout, LinuxCNC's #5063."""
    axis = str(ini.get("probe", "axis", str)).strip().lower()
    if axis not in letters:
        raise ini.fail(f"[probe] axis = {axis!r}: not one of the driven axes "
                       f"({', '.join(letters)})")
    cfg.probe_axis = axis
    cfg.probe_timeout_s = float(ini.get("probe", "timeout_s", float, 2.0))
    try:
        cfg.probed_includes_offset = ini.parser.getboolean("probe", "probed_includes_offset",
                                                           fallback=True)
    except ValueError:
        raise ini.fail(f"[probe] probed_includes_offset = "
                       f"{ini.parser.get('probe', 'probed_includes_offset')!r}: yes or "
                       "no") from None
    if not (math.isfinite(cfg.probe_timeout_s) and cfg.probe_timeout_s > 0):
        raise ini.fail(f"[probe] timeout_s = {cfg.probe_timeout_s:g} must be positive")


def axis_step_nm(path: Path, section: str, box_axis: str, model: ModelSpec | None,
                  given_um: float | None, need: bool) -> float | None:
    """An axis's step limit per sample line in nm: the model's ``axes.<name>.max_step_um``
    rounded up to nm as codegen does for the box (a model without it: codegen's default, the
    box's walk-back rate x its period), or ``max_step_um`` in the axis section (the smaller
    of the two when both are given). None when neither exists and no hash is expected."""
    if given_um is not None and not (math.isfinite(given_um) and given_um > 0):
        raise ConfigError(f"{path}: [{section}] max_step_um = {given_um:g} must be positive")
    steps = [given_um * 1000.0] if given_um is not None else []
    if model is not None:
        axes = model.axis_names
        if box_axis not in axes:
            raise ConfigError(f"{path}: [{section}] box_axis = {box_axis}: the model has axes "
                              f"{', '.join(axes) or '(none)'}")
        step_um = model.axis(box_axis).max_step_um
        if step_um is None:
            step_um = DEFAULT_AXIS_STEP_UM_PER_S * model.sample_period_s
        steps.append(float(math.ceil(step_um * 1000.0)))
    if not steps and need:
        raise ConfigError(f"{path}: [{section}] needs 'max_step_um' (the model's "
                          f"axes.{box_axis}.max_step_um) when [box] gives model_hash without "
                          "model = <model.json>")
    return min(steps) if steps else None
