"""Simulated thermal test runs of a vertical machining center (``host simulate``).

The machine (``host.sim.machine_model``) is a lumped thermal network driven by a spindle program
(``host.sim.spindle_programs``) and the shop air; thermocouples read their local temperature
through a first-order lag, with calibration offset, noise and the MAX31856 quantisation; gap
sensors read the tool-to-table displacement with noise. The run is written in the project's
CSV format with a ``.truth.json`` sidecar holding everything a test needs to know what a model
could at best achieve: the program, the effects and their parameters, the sensors' placement
and the noise-free displacement.

``SimConfig`` and the effects' parameters are ``host.sim.run_config``; the shop air and the
coolant pump ``host.sim.shop_floor``; what each effect adds ``host.sim.injected_effects``.

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
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from thermal_comp.contract import __version__
from thermal_comp.host.io import TIME_COLUMN, write_run
from thermal_comp.host.sim.injected_effects import EFFECT_MODELS, RunState
from thermal_comp.host.sim.machine_model import (
    AMBIENT_SENSOR,
    AMBIENT_SENSOR_TAU_S,
    AXES,
    Machine,
    SensorSpec,
    place_sensors,
)
from thermal_comp.host.sim.run_config import (
    EFFECT_DEFAULTS,
    EFFECTS,
    RPM_COLUMN,
    SimConfig,
    SimulationError,
    parse_effects,
    random_stream,
)
from thermal_comp.host.sim.shop_floor import AmbientProfile, coolant_schedule
from thermal_comp.host.sim.spindle_programs import SpindleProgram
from thermal_comp.host.sim.thermal_network import Modes, StepOperator

TRUTH_SCHEMA = "thermal-sim-truth/1"


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


class _StepwiseInputs:
    """Spindle speed (fraction of max) and pump state of a run, and their propagators.

    Each distinct (speed, pump, length) propagator is computed once, from the modes of its
    operating point, and reused.
    """

    def __init__(self, machine: Machine, program: SpindleProgram,
                 pump: list[tuple[float, float]]) -> None:
        self.machine = machine
        self.program = program
        self.pump = pump
        self.pump_starts = np.array([a for a, _ in pump])
        self.pump_ends = np.array([b for _, b in pump])
        self.modes: dict[tuple[float, bool], Modes] = {}
        self.ops: dict[tuple, StepOperator] = {}

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Where the inputs change, strictly between t0 and t1, in order."""
        cuts = set(self.program.boundaries_s().tolist())
        for a, b in self.pump:
            cuts.update((a, b))
        return np.array(sorted(c for c in cuts if t0 < c < t1))

    def at(self, x: float) -> tuple[float, bool]:
        s = float(self.program.rpm_at(x)) / self.program.max_rpm
        on = bool(self.pump) and bool(np.any((self.pump_starts <= x) & (x < self.pump_ends)))
        return s, on

    def operator(self, key: tuple[float, bool], length: float) -> StepOperator:
        k = (key, round(length, 9))
        if k not in self.ops:
            if key not in self.modes:
                self.modes[key] = self.machine.network.modes(self.machine.operating_point(*key))
            self.ops[k] = self.modes[key].step(length)
        return self.ops[k]


def simulate_nodes(machine: Machine, program: SpindleProgram, time_s: np.ndarray,
                   ambient: Callable[[np.ndarray], np.ndarray],
                   pump: list[tuple[float, float]] | None = None,
                   initial_c: np.ndarray | None = None) -> np.ndarray:
    """True node temperatures at ``time_s`` (uniform grid from 0), exact for stepwise inputs.

    Inputs change only at program segment boundaries and pump switchings; a sample interval
    containing such a change is split there, and a run of whole intervals with the same
    inputs shares one propagator.
    """
    net = machine.network
    t = np.asarray(time_s, dtype=float)
    if t.size < 1:
        return np.empty((0, net.n))
    h = float(t[1] - t[0]) if t.size > 1 else 0.0
    inputs = _StepwiseInputs(machine, program, pump or [])
    cuts = inputs.breakpoints(t[0], t[-1])
    x = (np.full(net.n, float(ambient(np.array(t[0])))) if initial_c is None
         else np.asarray(initial_c, dtype=float).copy())
    out = np.empty((t.size, net.n))
    out[0] = x
    if t.size == 1:
        return out
    # which sample intervals contain a breakpoint strictly inside
    first_cut = np.searchsorted(cuts, t[:-1], side="right")
    last_cut = np.searchsorted(cuts, t[1:], side="left")
    split = last_cut > first_cut
    mid_amb = np.asarray(ambient(t[:-1] + 0.5 * h), dtype=float)
    k = 0
    n_int = t.size - 1
    while k < n_int:
        if split[k]:
            edges = [t[k], *cuts[first_cut[k]:last_cut[k]].tolist(), t[k + 1]]
            x = _step_across_changes(inputs, ambient, x, edges)
            k += 1
            out[k] = x
            continue
        m = k  # a run of whole intervals with the same inputs: k .. m-1
        next_cut = cuts[first_cut[k]] if first_cut[k] < cuts.size else np.inf
        while m < n_int and not split[m] and t[m + 1] <= next_cut:
            m += 1
        op = inputs.operator(inputs.at(0.5 * (t[k] + t[k + 1])), h)
        x = _step_run(op, x, mid_amb[k:m], out[k + 1:m + 1])
        k = m
    return out


def _step_across_changes(inputs: _StepwiseInputs, ambient: Callable[[np.ndarray], np.ndarray],
                         x: np.ndarray, edges: list[float]) -> np.ndarray:
    """One sample interval whose inputs change at the inner ``edges``: piece by piece."""
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        op = inputs.operator(inputs.at(0.5 * (a + b)), b - a)
        x = op.phi @ x + op.gamma_amb * float(ambient(np.array(0.5 * (a + b)))) + op.gamma_q
    return x


def _step_run(op: StepOperator, x: np.ndarray, mid_ambient: np.ndarray, out: np.ndarray
              ) -> np.ndarray:
    """Whole intervals under one propagator; each state into ``out``, the last returned."""
    forcing = np.outer(mid_ambient, op.gamma_amb) + op.gamma_q
    phi = op.phi
    for j in range(mid_ambient.size):
        x = phi @ x + forcing[j]
        out[j] = x
    return x


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
    rng = random_stream(config.seed, 3)
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


def _check_step(config: SimConfig) -> None:
    if not (math.isfinite(config.dt_s) and config.dt_s > 0):
        raise SimulationError(f"--dt must be positive (got {config.dt_s:g})")
    if config.dt_s > 3600:
        raise SimulationError(f"--dt {config.dt_s:g} s is longer than an hour; the bearings "
                              "change within minutes")


def _n_samples(program: SpindleProgram, config: SimConfig) -> int:
    n = int(math.floor(program.duration_s / config.dt_s + 1e-9)) + 1
    if n < 2:
        raise SimulationError(f"run of {program.duration_s:g} s is shorter than one --dt step")
    return n


def simulate(program: SpindleProgram, config: SimConfig | None = None,
             machine: Machine | None = None) -> Simulation:
    """Simulate one run of ``program`` on ``machine`` (default: the documented VMC)."""
    config = config or SimConfig()
    machine = machine or Machine()
    _check_step(config)
    effects = parse_effects(config.effects)
    config = replace(config, effects=effects)
    n = _n_samples(program, config)
    time_s = np.arange(n) * config.dt_s
    sensors = place_sensors(config.n_sensors, config.machine_seed)
    names = machine.names

    ambient = AmbientProfile(config, program.duration_s)
    pump = coolant_schedule(config, program.duration_s) if "coolant" in effects else None
    nodes_c = simulate_nodes(machine, program, time_s, ambient, pump)
    reference = nodes_c[0].copy()
    run = RunState(machine, program, sensors, ambient, pump, nodes_c - reference, reference,
                    program.rpm_at(time_s))

    base = run.rise @ machine.coefficient_matrix()
    true = {axis: base[:, k].copy() for k, axis in enumerate(AXES)}
    components: dict[str, dict[str, np.ndarray]] = {}
    effect_truth: dict[str, dict] = {}
    for eff in effects:
        p = config.params(eff)
        comp = EFFECT_MODELS[eff](eff, p, run)
        for a, v in comp.items():
            true[a] = true[a] + v
        components[eff] = comp
        effect_truth[eff] = p

    rng = random_stream(config.seed, 4)
    measured = {a: true[a] + rng.normal(0.0, config.disp_noise_sd_um, n) for a in AXES}
    temps = _sensor_readings(sensors, names, nodes_c, ambient(time_s), time_s, config,
                             effect_truth.get("drift"))
    columns: dict[str, np.ndarray] = {**temps, RPM_COLUMN: run.rpm, **measured}
    truth = _truth_json(program, config, machine, run, nodes_c, effect_truth, true, components)
    return Simulation(time_s, columns, truth, names, nodes_c, true, components, sensors)


def _truth_json(program: SpindleProgram, config: SimConfig, machine: Machine, run: RunState,
                nodes_c: np.ndarray, effect_truth: dict[str, dict],
                true: dict[str, np.ndarray], components: dict[str, dict[str, np.ndarray]]
                ) -> dict:
    """The ``.truth.json`` sidecar: everything a test needs to judge a model of this run."""
    names = machine.names
    keep = sorted({p["node"] for p in effect_truth.values()
                   if p.get("node") in names and "sensor" not in p})
    return {
        "schema": TRUTH_SCHEMA,
        "tool_version": __version__,
        "seed": config.seed,
        "machine_seed": config.machine_seed,
        "dt_s": config.dt_s,
        "n_samples": int(nodes_c.shape[0]),
        "program": program.to_json(),
        "ambient": {"base_c": config.ambient_c, "start_hour": config.start_hour,
                    "wander_sd_c": config.wander_sd_c, "wander_tau_s": config.wander_tau_s,
                    "daily_cycle": "ambient" in config.effects},
        "effects": effect_truth,
        "noise": {"temperature_sd_c": config.temp_noise_sd_c, "quantum_c": config.quantum_c,
                  "displacement_sd_um": config.disp_noise_sd_um},
        "sensors": {**{s.name: s.to_json() for s in run.sensors},
                    AMBIENT_SENSOR: {"node": "ambient air", "tau_s": AMBIENT_SENSOR_TAU_S}},
        "reference_c": {nm: round(float(v), 6) for nm, v in zip(names, run.reference,
                                                                  strict=True)},
        "displacement_coefficients_um_per_k": machine.displacement,
        "displacement_true_um": {a: _rounded(v) for a, v in true.items()},
        "components_um": {e: {a: _rounded(v) for a, v in c.items()}
                          for e, c in components.items()},
        "nodes_c": {nm: _rounded(nodes_c[:, names.index(nm)]) for nm in keep},
    }


def _rounded(v: np.ndarray, decimals: int = 3) -> list[float]:
    return np.round(np.asarray(v, dtype=float), decimals).tolist()


def truth_path(csv_path: str | Path) -> Path:
    """RUN.csv -> RUN.truth.json (the sidecar next to the run)."""
    p = Path(csv_path)
    return p.with_name((p.stem if p.suffix.lower() == ".csv" else p.name) + ".truth.json")


def write_simulation(sim: Simulation, path: str | Path, precision: int = 6) -> Path:
    """Write the run CSV (host.io.write_run) and its truth sidecar, both atomically."""
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
