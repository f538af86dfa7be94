"""Simulated thermal test runs of a vertical machining center (``host simulate``).

The machine (``host.sim.machine_model``) is a lumped thermal network driven by a spindle program
(``host.sim.spindle_programs``) and the shop air; thermocouples read their local temperature
through a first-order lag, with calibration offset, noise and the MAX31856 quantisation; gap
sensors read the tool-to-table displacement with noise. The run is written in the project's
CSV format with a ``.truth.json`` sidecar holding everything a test needs to know what a model
could at best achieve: the program, the effects and their parameters, the sensors' placement
and the noise-free displacement.

Without effects the displacement is a linear function of the measured nodes' rises, so a
static linear model of a few thermocouples explains it up to noise and sensor lag. Each effect
adds what such a model cannot capture but one candidate term of ``contract.terms`` can (the truth
file names that term under ``matching_terms``):

  lag        the hidden spindle shaft grows too (pseudo-hysteresis)   lag(bearing sensor, tau)
  ambient    a daily cycle of shop air, felt by the frame bulk hours later  lag(T_amb, tau)
  speed      centrifugal growth of the spindle, instantaneous, ~ n^2      speed2(spindle_rpm)
  drift      one thermocouple's calibration drifts linearly                time
  coolant    an unlogged pump floods the table with warm coolant, the
             table body follows the table top slowly                     lag(table sensor, tau)
  nonlinear  a displacement term in the square of a node's rise           square(sensor, ref)
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from contract import __version__
from contract.errors import InputError
from host.io import TIME_COLUMN, write_run
from host.sim.machine_model import (
    AMBIENT_SENSOR,
    AMBIENT_SENSOR_TAU_S,
    AXES,
    Machine,
    SensorSpec,
    place_sensors,
)
from host.sim.spindle_programs import SpindleProgram
from host.sim.thermal_network import Modes, StepOperator

EFFECTS = ("lag", "ambient", "speed", "drift", "coolant", "nonlinear")
RPM_COLUMN = "spindle_rpm"
TRUTH_SCHEMA = "thermal-sim-truth/1"
MAX31856_STEP_C = 0.0078125

EFFECT_DEFAULTS: dict[str, dict] = {
    "lag": {"node": "shaft", "coef_um_per_k": {"dz_um": -5.0},
            "meaning": "thermal growth of the rotating spindle shaft (no thermocouple)"},
    "ambient": {"amplitude_c": 2.0, "period_h": 24.0, "peak_hour": 15.0, "weather_sd_c": 0.8,
                "weather_tau_h": 2.0, "node": "frame_core",
                "coef_um_per_k": {"dz_um": 10.0},
                "meaning": "daily cycle of shop air; the frame bulk follows hours later"},
    "speed": {"coef_um_at_max": {"dz_um": -10.0}, "exponent": 2.0,
              "meaning": "centrifugal and gyroscopic growth of the spindle nose, no lag"},
    "drift": {"node": "column_front", "rate_c_per_h": 0.25,
              "meaning": "one thermocouple's calibration drifts linearly with time"},
    "coolant": {"on_min": 15.0, "off_min": 25.0, "jitter_min": 5.0, "node": "table_body",
                "coef_um_per_k": {"dz_um": -6.0},
                "meaning": "unlogged coolant pump floods the table with warm coolant"},
    "nonlinear": {"node": "gearbox", "coef_um_per_k2": {"dy_um": 0.12, "dz_um": -0.06},
                  "meaning": "a displacement term in the square of a node's rise"},
}


class SimulationError(InputError):
    """The simulation cannot run as asked (bad effect name, step, sensor count...)."""


@dataclass(frozen=True)
class SimConfig:
    """Everything but the spindle program that decides a simulated run."""

    n_sensors: int = 16
    dt_s: float = 60.0
    seed: int = 0
    machine_seed: int = 0
    effects: tuple[str, ...] = ()
    ambient_c: float = 20.0
    start_hour: float = 8.0  # time of day at t = 0 (phase of the daily cycle)
    wander_sd_c: float = 0.15  # slow random wander of shop air (always present)
    wander_tau_s: float = 3600.0
    temp_noise_sd_c: float = 0.01
    quantum_c: float = MAX31856_STEP_C
    disp_noise_sd_um: float = 0.1
    effect_params: dict[str, dict] = field(default_factory=dict)  # overrides of EFFECT_DEFAULTS

    def params(self, effect: str) -> dict:
        out = json.loads(json.dumps(EFFECT_DEFAULTS[effect]))
        out.update(self.effect_params.get(effect, {}))
        return out


@dataclass
class Simulation:
    """A simulated run: CSV columns, the hidden truth and the true node temperatures."""

    time_s: np.ndarray
    columns: dict[str, np.ndarray]
    truth: dict
    node_names: list[str]
    nodes_c: np.ndarray  # (n_samples, n_nodes) true temperatures
    displacement_true: dict[str, np.ndarray]
    components: dict[str, dict[str, np.ndarray]]
    sensors: list[SensorSpec]

    @property
    def sensor_names(self) -> list[str]:
        return [s.name for s in self.sensors] + [AMBIENT_SENSOR]

    def node(self, name: str) -> np.ndarray:
        return self.nodes_c[:, self.node_names.index(name)]


def parse_effects(text: str | Iterable[str] | None) -> tuple[str, ...]:
    """'lag,speed' or ['lag', 'speed'] or 'all' to a checked, ordered tuple."""
    if text is None:
        return ()
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [i.strip() for i in items if i.strip()]
    if names == ["all"]:
        return EFFECTS
    for n in names:
        if n not in EFFECTS:
            raise SimulationError(f"unknown effect '{n}' (known: {', '.join(EFFECTS)}, all)")
    return tuple(e for e in EFFECTS if e in names)


def _rng(seed: int, stream: int) -> np.random.Generator:
    """Independent stream per purpose, so switching one effect never reshuffles another's noise."""
    return np.random.default_rng([seed, stream])


def _ou_knots(rng: np.random.Generator, n: int, knot_s: float, sd: float,
              tau_s: float) -> np.ndarray:
    """Ornstein-Uhlenbeck process (stationary sd, correlation time tau) at n knots, from 0."""
    a = math.exp(-knot_s / tau_s)
    w = np.empty(n)
    w[0] = rng.normal(0.0, sd)
    shocks = rng.normal(0.0, sd * math.sqrt(1 - a * a), n)
    for k in range(1, n):
        w[k] = a * w[k - 1] + shocks[k]
    return w - w[0]


class AmbientProfile:
    """Shop air: base + slow random wander; the ``ambient`` effect adds the day's cycle.

    The day (``ambient`` on) is a daily sinusoid whose amplitude and peak hour vary from day to
    day (seeded), plus weather and HVAC swings (a slower, larger random process): a real shop
    day, not a pure sine, which any two lagged signals would span.
    """

    KNOT_S = 300.0

    def __init__(self, config: SimConfig, duration_s: float) -> None:
        self.base = config.ambient_c
        n = int(math.ceil(duration_s / self.KNOT_S)) + 2
        self.knots_s = np.arange(n) * self.KNOT_S
        self.wander = _ou_knots(_rng(config.seed, 2), n, self.KNOT_S, config.wander_sd_c,
                                config.wander_tau_s)
        self.start_hour = config.start_hour
        self.daily: dict | None = None
        self.weather = np.zeros(n)
        if "ambient" in config.effects:
            d = config.params("ambient")
            rng = _rng(config.seed, 6)
            self.amplitude_c = float(d["amplitude_c"] * rng.uniform(0.7, 1.3))
            self.peak_hour = float(d["peak_hour"] + rng.uniform(-2.0, 2.0))
            self.period_h = float(d["period_h"])
            self.weather = _ou_knots(rng, n, self.KNOT_S, d["weather_sd_c"],
                                     d["weather_tau_h"] * 3600.0)
            self.daily = {"amplitude_c": round(self.amplitude_c, 4),
                          "peak_hour": round(self.peak_hour, 4), "period_h": self.period_h}

    def daily_c(self, t_s: np.ndarray) -> np.ndarray:
        """The day's cycle (0 at t = 0) plus weather; zero without the ``ambient`` effect."""
        t = np.asarray(t_s, dtype=float)
        if self.daily is None:
            return np.zeros_like(t)
        hour = self.start_hour + t / 3600.0

        def cyc(h: np.ndarray | float) -> np.ndarray:
            return self.amplitude_c * np.cos(2 * np.pi * (h - self.peak_hour) / self.period_h)

        return cyc(hour) - cyc(self.start_hour) + np.interp(t, self.knots_s, self.weather)

    def __call__(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return self.base + np.interp(t, self.knots_s, self.wander) + self.daily_c(t)


def coolant_schedule(config: SimConfig, duration_s: float) -> list[tuple[float, float]]:
    """(start, end) of each pump run: on/off cycles with seeded jitter, unknown to the logger."""
    p = config.params("coolant")
    rng = _rng(config.seed, 5)
    out = []
    t = float(rng.uniform(0, p["off_min"])) * 60.0
    while t < duration_s:
        on = max(1.0, p["on_min"] + rng.uniform(-p["jitter_min"], p["jitter_min"])) * 60.0
        off = max(1.0, p["off_min"] + rng.uniform(-p["jitter_min"], p["jitter_min"])) * 60.0
        out.append((t, min(t + on, duration_s)))
        t += on + off
    return out


def simulate_nodes(machine: Machine, program: SpindleProgram, time_s: np.ndarray,
                   ambient: Callable[[np.ndarray], np.ndarray],
                   pump: list[tuple[float, float]] | None = None,
                   initial_c: np.ndarray | None = None) -> np.ndarray:
    """True node temperatures at ``time_s`` (uniform grid from 0), exact for stepwise inputs.

    Inputs change only at program segment boundaries and pump switchings; a sample interval
    containing such a change is split there. Each distinct (speed, pump, length) propagator
    is computed once (from the modes of its operating point) and reused.
    """
    net = machine.network
    t = np.asarray(time_s, dtype=float)
    if t.size < 1:
        return np.empty((0, net.n))
    h = float(t[1] - t[0]) if t.size > 1 else 0.0
    pump = pump or []
    # breakpoints: where the inputs change
    cuts = set(program.boundaries_s().tolist())
    for a, b in pump:
        cuts.update((a, b))
    cuts_arr = np.array(sorted(c for c in cuts if t[0] < c < t[-1]))
    pump_starts = np.array([a for a, _ in pump])
    pump_ends = np.array([b for _, b in pump])

    def inputs_at(x: float) -> tuple[float, bool]:
        s = float(program.rpm_at(x)) / program.max_rpm
        on = bool(pump) and bool(np.any((pump_starts <= x) & (x < pump_ends)))
        return s, on

    modes: dict[tuple[float, bool], Modes] = {}
    ops: dict[tuple, StepOperator] = {}

    def operator(key: tuple[float, bool], length: float) -> StepOperator:
        k = (key, round(length, 9))
        if k not in ops:
            if key not in modes:
                modes[key] = net.modes(machine.operating_point(*key))
            ops[k] = modes[key].step(length)
        return ops[k]

    x = (np.full(net.n, float(ambient(np.array(t[0])))) if initial_c is None
         else np.asarray(initial_c, dtype=float).copy())
    out = np.empty((t.size, net.n))
    out[0] = x
    if t.size == 1:
        return out
    # which sample intervals contain a breakpoint strictly inside
    first_cut = np.searchsorted(cuts_arr, t[:-1], side="right")
    last_cut = np.searchsorted(cuts_arr, t[1:], side="left")
    split = last_cut > first_cut
    mid_amb = np.asarray(ambient(t[:-1] + 0.5 * h), dtype=float)
    k = 0
    n_int = t.size - 1
    while k < n_int:
        if split[k]:
            edges = [t[k], *cuts_arr[first_cut[k]:last_cut[k]].tolist(), t[k + 1]]
            for a, b in zip(edges[:-1], edges[1:], strict=True):
                op = operator(inputs_at(0.5 * (a + b)), b - a)
                x = op.phi @ x + op.gamma_amb * float(ambient(np.array(0.5 * (a + b)))) \
                    + op.gamma_q
            k += 1
            out[k] = x
            continue
        key = inputs_at(0.5 * (t[k] + t[k + 1]))
        # a run of whole intervals with the same inputs
        m = k
        next_cut = cuts_arr[first_cut[k]] if first_cut[k] < cuts_arr.size else np.inf
        while m < n_int and not split[m] and t[m + 1] <= next_cut:
            m += 1
        op = operator(key, h)
        forcing = np.outer(mid_amb[k:m], op.gamma_amb) + op.gamma_q
        phi = op.phi
        for j in range(m - k):
            x = phi @ x + forcing[j]
            out[k + 1 + j] = x
        k = m
    return out


def _sensor_readings(sensors: list[SensorSpec], names: list[str], nodes_c: np.ndarray,
                     ambient_c: np.ndarray, time_s: np.ndarray, config: SimConfig,
                     drift: dict | None) -> dict[str, np.ndarray]:
    """Thermocouple columns: local temperature -> first-order lag -> offset, drift, noise, LSB."""
    dt = config.dt_s
    mix = np.zeros((len(sensors), len(names)))
    for i, s in enumerate(sensors):
        mix[i, names.index(s.node)] += s.weight
        mix[i, names.index(s.neighbour)] += 1.0 - s.weight
    local = nodes_c @ mix.T
    rng = _rng(config.seed, 3)
    noise = rng.normal(0.0, config.temp_noise_sd_c, (time_s.size, len(sensors) + 1))
    q = config.quantum_c
    taus = np.array([s.tau_s for s in sensors] + [AMBIENT_SENSOR_TAU_S])
    lagged = _lag_columns(np.column_stack([local, ambient_c]), -np.expm1(-dt / taus))
    out: dict[str, np.ndarray] = {}
    for i, s in enumerate([*sensors, None]):
        y = lagged[:, i] + noise[:, i]
        if s is not None:
            y += s.offset_c
            if drift is not None and drift["sensor"] == s.name:
                y += drift["rate_c_per_h"] * time_s / 3600.0
        out[AMBIENT_SENSOR if s is None else s.name] = np.round(y / q) * q if q > 0 else y
    return out


def _lag_columns(x: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """host.fitting.first_order_lag on every column at once (y[0] = x[0]: settled at the start)."""
    y = np.empty_like(x)
    y[0] = x[0]
    state = x[0].copy()
    for k in range(1, x.shape[0]):
        state += alpha * (x[k] - state)
        y[k] = state
    return y


def _first_sensor_on(sensors: list[SensorSpec], node: str) -> SensorSpec:
    """The most faithful sensor on a node (largest weight, then lowest number)."""
    on = [s for s in sensors if s.node == node]
    if not on:
        raise SimulationError(f"no thermocouple on node '{node}': use more --sensors")
    return max(on, key=lambda s: (s.weight, -sensors.index(s)))


def _node_tau_s(machine: Machine, node: str, pump_on: bool = False) -> float:
    """C / (sum of its conductances): the node's own time constant, neighbours held fixed."""
    net = machine.network
    i = net.index(node)
    op = machine.operating_point(0.0, pump_on)
    return float(net.capacity[i] / net.stiffness(op)[i, i])


def simulate(program: SpindleProgram, config: SimConfig | None = None,
             machine: Machine | None = None) -> Simulation:
    """Simulate one run of ``program`` on ``machine`` (default: the documented VMC)."""
    config = config or SimConfig()
    machine = machine or Machine()
    if not (math.isfinite(config.dt_s) and config.dt_s > 0):
        raise SimulationError(f"--dt must be positive (got {config.dt_s:g})")
    if config.dt_s > 3600:
        raise SimulationError(f"--dt {config.dt_s:g} s is longer than an hour; the bearings "
                              "change within minutes")
    effects = parse_effects(config.effects)
    config = replace(config, effects=effects)
    n = int(math.floor(program.duration_s / config.dt_s + 1e-9)) + 1
    if n < 2:
        raise SimulationError(f"run of {program.duration_s:g} s is shorter than one --dt step")
    time_s = np.arange(n) * config.dt_s
    sensors = place_sensors(config.n_sensors, config.machine_seed)
    names = machine.names

    ambient = AmbientProfile(config, program.duration_s)
    pump = coolant_schedule(config, program.duration_s) if "coolant" in effects else None
    nodes_c = simulate_nodes(machine, program, time_s, ambient, pump)
    reference = nodes_c[0].copy()
    rise = nodes_c - reference
    rpm = program.rpm_at(time_s)

    base = rise @ machine.coefficient_matrix()
    true = {axis: base[:, k].copy() for k, axis in enumerate(AXES)}
    components: dict[str, dict[str, np.ndarray]] = {}
    effect_truth: dict[str, dict] = {}
    drift = None
    for eff in effects:
        p = config.params(eff)
        comp: dict[str, np.ndarray] = {}
        if eff in ("lag", "ambient", "coolant"):
            r = rise[:, names.index(p["node"])]
            comp = {a: c * r for a, c in p["coef_um_per_k"].items()}
            pump_on = eff == "coolant"
            p["node_tau_s"] = round(_node_tau_s(machine, p["node"], False), 1)
            if eff == "lag":
                src = _first_sensor_on(sensors, "bearing_front").name
            elif eff == "ambient":
                src = AMBIENT_SENSOR
                p["day"] = ambient.daily
            else:
                src = _first_sensor_on(sensors, "table").name
                p["schedule_s"] = [[round(a, 3), round(b, 3)] for a, b in (pump or [])]
                p["pump_heat_w"] = machine.pump_heat_w
                p["pump_table_w_per_k"] = machine.pump_table_w_per_k
                p["node_tau_pump_on_s"] = round(_node_tau_s(machine, p["node"], pump_on), 1)
            p["matching_terms"] = [{"kind": "lag", "source": src, "tau_s": p["node_tau_s"]}]
            if eff == "ambient":
                p["matching_terms"].insert(0, {"kind": "temp", "source": src})
        elif eff == "speed":
            frac = rpm / program.max_rpm
            comp = {a: c * frac ** p["exponent"] for a, c in p["coef_um_at_max"].items()}
            p["matching_terms"] = [{"kind": "speed2", "source": RPM_COLUMN}]
        elif eff == "nonlinear":
            r = rise[:, names.index(p["node"])]
            comp = {a: c * r * r for a, c in p["coef_um_per_k2"].items()}
            s = _first_sensor_on(sensors, p["node"])
            p["reference_c"] = round(float(reference[names.index(p["node"])]), 6)
            p["matching_terms"] = [{"kind": "square", "source": s.name,
                                    "ref_c": round(p["reference_c"] + s.offset_c, 6)}]
        elif eff == "drift":
            s = _first_sensor_on(sensors, p["node"])
            p["sensor"] = s.name
            drift = p
            p["matching_terms"] = [{"kind": "time"}]
        for a, v in comp.items():
            true[a] = true[a] + v
        components[eff] = comp
        effect_truth[eff] = p

    rng = _rng(config.seed, 4)
    measured = {a: true[a] + rng.normal(0.0, config.disp_noise_sd_um, n) for a in AXES}
    amb = ambient(time_s)
    temps = _sensor_readings(sensors, names, nodes_c, amb, time_s, config, drift)
    columns: dict[str, np.ndarray] = {**temps, RPM_COLUMN: rpm, **measured}

    keep = sorted({p["node"] for p in effect_truth.values()
                   if p.get("node") in names and "sensor" not in p})
    truth = {
        "schema": TRUTH_SCHEMA,
        "tool_version": __version__,
        "seed": config.seed,
        "machine_seed": config.machine_seed,
        "dt_s": config.dt_s,
        "n_samples": n,
        "program": program.to_json(),
        "ambient": {"base_c": config.ambient_c, "start_hour": config.start_hour,
                    "wander_sd_c": config.wander_sd_c, "wander_tau_s": config.wander_tau_s,
                    "daily_cycle": "ambient" in effects},
        "effects": effect_truth,
        "noise": {"temperature_sd_c": config.temp_noise_sd_c, "quantum_c": config.quantum_c,
                  "displacement_sd_um": config.disp_noise_sd_um},
        "sensors": {**{s.name: s.to_json() for s in sensors},
                    AMBIENT_SENSOR: {"node": "ambient air", "tau_s": AMBIENT_SENSOR_TAU_S}},
        "reference_c": {nm: round(float(v), 6) for nm, v in zip(names, reference, strict=True)},
        "displacement_coefficients_um_per_k": machine.displacement,
        "displacement_true_um": {a: _rounded(v) for a, v in true.items()},
        "components_um": {e: {a: _rounded(v) for a, v in c.items()}
                          for e, c in components.items()},
        "nodes_c": {nm: _rounded(nodes_c[:, names.index(nm)]) for nm in keep},
    }
    return Simulation(time_s, columns, truth, names, nodes_c, true, components, sensors)


def _rounded(v: np.ndarray, decimals: int = 3) -> list[float]:
    return np.round(np.asarray(v, dtype=float), decimals).tolist()


def truth_path(csv_path: str | Path) -> Path:
    """RUN.csv -> RUN.truth.json (the sidecar next to the run)."""
    p = Path(csv_path)
    return p.with_name((p.stem if p.suffix.lower() == ".csv" else p.name) + ".truth.json")


def write_simulation(sim: Simulation, path: str | Path, precision: int = 6) -> Path:
    """Write the run CSV (host.io.runs.write_run) and its truth sidecar, both atomically."""
    path = Path(path)
    write_run(path, sim.time_s, sim.columns, precision=precision)
    tp = truth_path(path)
    tmp = tp.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(sim.truth, separators=(",", ":")) + "\n")
    os.replace(tmp, tp)
    return tp


def load_truth(csv_path: str | Path) -> dict:
    tp = truth_path(csv_path)
    if not tp.is_file():
        raise FileNotFoundError(f"{tp}: no truth sidecar for {csv_path}")
    return json.loads(tp.read_text())


__all__ = ["EFFECTS", "EFFECT_DEFAULTS", "RPM_COLUMN", "SimConfig", "Simulation",
           "SimulationError", "TIME_COLUMN", "load_truth", "parse_effects", "simulate",
           "simulate_nodes", "truth_path", "write_simulation"]
