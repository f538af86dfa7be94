"""The effects the simulator can inject: what each adds to the displacement, and its truth.

Each effect model returns its displacement components per axis and records into its
parameters ``p`` what a test needs to judge a model: among them ``matching_terms``, the
candidate term of ``contract.terms`` that can express it (``host.sim.simulator`` explains the
effects).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from thermal_comp.host.sim.machine_model import AMBIENT_SENSOR, Machine, SensorSpec
from thermal_comp.host.sim.run_config import RPM_COLUMN, SimulationError
from thermal_comp.host.sim.shop_floor import AmbientProfile
from thermal_comp.host.sim.spindle_programs import SpindleProgram


def first_sensor_on(sensors: list[SensorSpec], node: str) -> SensorSpec:
    """The most faithful sensor on a node (largest weight, then lowest number)."""
    on = [s for s in sensors if s.node == node]
    if not on:
        raise SimulationError(f"no thermocouple on node '{node}': use more --sensors")
    return max(on, key=lambda s: (s.weight, -sensors.index(s)))


def node_tau_s(machine: Machine, node: str, pump_on: bool = False) -> float:
    """C / (sum of its conductances): the node's own time constant, neighbours held fixed."""
    net = machine.network
    i = net.index(node)
    op = machine.operating_point(0.0, pump_on)
    return float(net.capacity[i] / net.stiffness(op)[i, i])


@dataclass
class RunState:
    """What every effect may read: the machine, its sensors and the true node rises."""

    machine: Machine
    program: SpindleProgram
    sensors: list[SensorSpec]
    ambient: AmbientProfile
    pump: list[tuple[float, float]] | None
    rise: np.ndarray  # (n_samples, n_nodes) node temperatures minus their start
    reference: np.ndarray  # node temperatures at the start
    rpm: np.ndarray

    def node_rise(self, node: str) -> np.ndarray:
        return self.rise[:, self.machine.names.index(node)]


def node_effect(eff: str, p: dict, run: RunState) -> dict[str, np.ndarray]:
    """lag, ambient, coolant: a hidden node's rise moves the tool; a lag of a sensor matches."""
    comp = {a: c * run.node_rise(p["node"]) for a, c in p["coef_um_per_k"].items()}
    p["node_tau_s"] = round(node_tau_s(run.machine, p["node"], False), 1)
    if eff == "lag":
        src = first_sensor_on(run.sensors, "bearing_front").name
    elif eff == "ambient":
        src = AMBIENT_SENSOR
        p["day"] = run.ambient.daily
    else:
        src = first_sensor_on(run.sensors, "table").name
        p["schedule_s"] = [[round(a, 3), round(b, 3)] for a, b in (run.pump or [])]
        p["pump_heat_w"] = run.machine.pump_heat_w
        p["pump_table_w_per_k"] = run.machine.pump_table_w_per_k
        p["node_tau_pump_on_s"] = round(node_tau_s(run.machine, p["node"], True), 1)
    p["matching_terms"] = [{"kind": "lag", "source": src, "tau_s": p["node_tau_s"]}]
    if eff == "ambient":
        p["matching_terms"].insert(0, {"kind": "temp", "source": src})
    return comp


def speed_effect(eff: str, p: dict, run: RunState) -> dict[str, np.ndarray]:
    frac = run.rpm / run.program.max_rpm
    p["matching_terms"] = [{"kind": "speed2", "source": RPM_COLUMN}]
    return {a: c * frac ** p["exponent"] for a, c in p["coef_um_at_max"].items()}


def nonlinear_effect(eff: str, p: dict, run: RunState) -> dict[str, np.ndarray]:
    r = run.node_rise(p["node"])
    s = first_sensor_on(run.sensors, p["node"])
    p["reference_c"] = round(float(run.reference[run.machine.names.index(p["node"])]), 6)
    p["matching_terms"] = [{"kind": "square", "source": s.name,
                            "ref_c": round(p["reference_c"] + s.offset_c, 6)}]
    return {a: c * r * r for a, c in p["coef_um_per_k2"].items()}


def drift_effect(eff: str, p: dict, run: RunState) -> dict[str, np.ndarray]:
    """No displacement: one thermocouple's reading drifts (``_sensor_readings``)."""
    p["sensor"] = first_sensor_on(run.sensors, p["node"]).name
    p["matching_terms"] = [{"kind": "time"}]
    return {}


# effect -> its displacement components per axis; each also records its truth into ``p``
EFFECT_MODELS: dict[str, Callable[[str, dict, RunState], dict[str, np.ndarray]]] = {
    "lag": node_effect, "ambient": node_effect, "coolant": node_effect,
    "speed": speed_effect, "nonlinear": nonlinear_effect, "drift": drift_effect}
