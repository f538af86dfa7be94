"""The simulated vertical machining center: its thermal network, heat sources, geometry and sensors.

Every number here is documented (with its physical meaning) in docs/simulator.md; change them
together. Temperatures in degC, heat in W, capacities in J/K, conductances in W/K, displacements
in um. ``s`` is the spindle speed as a fraction of max speed.

Hidden nodes (``measured=False``) carry no thermocouple: the rotating spindle shaft, the bulk
of the frame castings and the table body. They only move the tool when their effect is on
(``host.sim.injected_effects``), so without effects the displacement is an exact linear
function of the measured nodes, which is what a static linear model can learn.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.host.sim.thermal_network import OperatingPoint, ThermalNetwork

AXES = ("dx_um", "dy_um", "dz_um")


@dataclass(frozen=True)
class NodeSpec:
    name: str
    capacity_j_per_k: float
    to_ambient_w_per_k: float  # convection + radiation to the shop air at standstill
    speed_gain: float  # convection grows as g0 * (1 + speed_gain * s): air stirred by rotation
    measured: bool
    meaning: str


@dataclass(frozen=True)
class SourceSpec:
    """Heat Q = watts_at_max * s**exponent into ``node`` (friction, losses) while s > 0."""

    node: str
    watts_at_max: float
    exponent: float
    meaning: str


NODES: tuple[NodeSpec, ...] = (
    NodeSpec("bearing_front", 4.0e3, 2.0, 1.5, True, "front spindle bearing set and its housing"),
    NodeSpec("bearing_rear", 3.5e3, 1.5, 1.5, True, "rear spindle bearing and its housing"),
    NodeSpec("shaft", 7.74e3, 0.8, 0.0, False, "rotating spindle shaft (no thermocouple reaches)"),
    NodeSpec("motor", 8.0e3, 3.0, 1.5, True, "spindle motor (fan-cooled)"),
    NodeSpec("gearbox", 8.0e3, 3.0, 0.5, True, "gearbox / belt pulley housing"),
    NodeSpec("headstock", 500.0e3, 5.0, 0.3, True, "headstock (spindle head) casting"),
    NodeSpec("column_front", 500.0e3, 10.0, 0.0, True, "front wall of the column (guideways)"),
    NodeSpec("column_back", 500.0e3, 10.0, 0.0, True, "back wall of the column"),
    NodeSpec("base_front", 1200.0e3, 12.0, 0.0, True, "front of the bed (under the table)"),
    NodeSpec("base_back", 1200.0e3, 12.0, 0.0, True, "back of the bed (under the column)"),
    NodeSpec("table", 15.0e3, 3.0, 0.0, True, "table top, where coolant runs"),
    NodeSpec("table_body", 39.6e3, 3.0, 0.0, False, "table and saddle body"),
    NodeSpec("tank", 400.0e3, 15.0, 0.0, True, "coolant / lubricant tank"),
    NodeSpec("frame_core", 2000.0e3, 2000.0e3 / (2 * 3600.0), 0.0, False,
             "bulk of column and base castings and the foundation, following shop air"),
)

# (node a, node b, conductance W/K, meaning)
LINKS: tuple[tuple[str, str, float, str], ...] = (
    ("bearing_front", "headstock", 8.0, "bearing outer ring to housing bore"),
    ("bearing_rear", "headstock", 6.0, "rear bearing housing to headstock"),
    ("bearing_front", "shaft", 1.5, "through the rolling elements"),
    ("bearing_rear", "shaft", 1.5, "through the rolling elements"),
    ("gearbox", "shaft", 0.5, "pulley hub to shaft end"),
    ("bearing_rear", "gearbox", 2.0, "rear housing to gearbox flange"),
    ("motor", "headstock", 3.0, "motor flange on the head"),
    ("motor", "gearbox", 1.0, "motor shaft and belt"),
    ("gearbox", "headstock", 8.0, "gearbox bolted on the head"),
    ("headstock", "column_front", 30.0, "head slides on the front guideways"),
    ("column_front", "column_back", 8.0, "column ribs"),
    ("column_front", "base_front", 6.0, "column foot, front"),
    ("column_back", "base_back", 6.0, "column foot, back"),
    ("base_front", "base_back", 8.0, "bed ribs"),
    ("table", "table_body", 15.0, "table top into its body"),
    ("table_body", "base_front", 4.0, "saddle on the bed guideways"),
    ("tank", "base_back", 1.0, "tank standing against the bed"),
    ("bearing_front", "tank", 0.5, "lubricant circulation carries bearing heat to the tank"),
    ("bearing_rear", "tank", 0.5, "lubricant circulation carries bearing heat to the tank"),
)

SOURCES: tuple[SourceSpec, ...] = (
    SourceSpec("bearing_front", 160.0, 1.7, "bearing friction (Palmgren: grows as n^1.7)"),
    SourceSpec("bearing_rear", 100.0, 1.7, "bearing friction (Palmgren: grows as n^1.7)"),
    SourceSpec("motor", 60.0, 1.0, "motor iron losses (grow with frequency)"),
    SourceSpec("motor", 200.0, 2.0, "motor windage and fan (grow as n^2)"),
    SourceSpec("gearbox", 220.0, 1.5, "gear churning and belt losses"),
)

# um of tool-to-table displacement per kelvin of a measured node's rise (see docs for signs).
DISPLACEMENT: dict[str, dict[str, float]] = {
    "dx_um": {"motor": -1.0, "gearbox": -0.6, "headstock": 0.15},
    "dy_um": {"headstock": -3.0, "bearing_front": -0.5, "column_front": 35.0,
              "column_back": -35.0, "base_front": 4.0, "base_back": -4.0},
    "dz_um": {"bearing_front": -2.0, "headstock": -5.0, "column_front": 3.0,
              "column_back": 3.0, "base_front": -0.5, "base_back": 0.5},
}

# Coolant pump (only runs when the ``coolant`` effect is on): it warms the coolant and, while
# running, floods the table with it.
PUMP_HEAT_W = 350.0
PUMP_TABLE_W_PER_K = 80.0

# Placement of thermocouples: (node, neighbour); a sensor reads w*T_node + (1-w)*T_neighbour.
# The first pass puts one sensor on each measured node (w = 1); later sensors are near-duplicates
# around the hottest, most instrumented parts, cycling through DUPLICATE_ORDER.
FIRST_PASS: tuple[tuple[str, str], ...] = (
    ("bearing_front", "headstock"), ("bearing_rear", "headstock"), ("motor", "headstock"),
    ("gearbox", "headstock"), ("headstock", "column_front"), ("column_front", "headstock"),
    ("column_back", "column_front"), ("base_front", "base_back"), ("base_back", "base_front"),
    ("table", "base_front"), ("tank", "base_back"),
)
DUPLICATE_ORDER = ("headstock", "gearbox", "column_front", "bearing_front", "motor", "column_back",
                   "base_front", "bearing_rear", "base_back", "table", "tank")
DUPLICATE_NEIGHBOUR = {node: nbr for node, nbr in FIRST_PASS}
DUPLICATE_WEIGHT = (0.6, 0.95)  # range of w for near-duplicates
SENSOR_TAU_S = (10.0, 60.0)  # thermocouple response time range (glued surface junction)
SENSOR_OFFSET_SD_C = 0.15  # calibration offset of each channel
AMBIENT_SENSOR = "T_amb"
AMBIENT_SENSOR_TAU_S = 60.0


@dataclass(frozen=True)
class SensorSpec:
    name: str
    node: str
    neighbour: str
    weight: float
    tau_s: float
    offset_c: float

    def to_json(self) -> dict:
        return {"node": self.node, "neighbour": self.neighbour, "weight": self.weight,
                "tau_s": self.tau_s, "offset_c": self.offset_c}


def sensor_name(i: int, n: int) -> str:
    """T01..Tnn, zero-padded to the width of n (T001.. for 100 and more)."""
    return f"T{i + 1:0{max(2, len(str(n)))}d}"


def place_sensors(n_sensors: int, machine_seed: int = 0) -> list[SensorSpec]:
    """Thermocouple positions, time constants and offsets of the machine (fixed by the seed)."""
    if n_sensors < 1:
        raise InputError(f"--sensors must be at least 1 (got {n_sensors})")
    rng = np.random.default_rng([machine_seed, 1])
    out: list[SensorSpec] = []
    for i in range(n_sensors):
        if i < len(FIRST_PASS):
            node, nbr = FIRST_PASS[i]
            w = 1.0
        else:
            node = DUPLICATE_ORDER[(i - len(FIRST_PASS)) % len(DUPLICATE_ORDER)]
            nbr = DUPLICATE_NEIGHBOUR[node]
            w = float(np.round(rng.uniform(*DUPLICATE_WEIGHT), 3))
        tau = float(np.round(rng.uniform(*SENSOR_TAU_S), 1))
        offset = float(np.round(rng.normal(0.0, SENSOR_OFFSET_SD_C), 3))
        out.append(SensorSpec(sensor_name(i, n_sensors), node, nbr, w, tau, offset))
    return out


@dataclass
class Machine:
    """The VMC: network, heat sources, geometry coefficients. Defaults are the documented ones."""

    nodes: tuple[NodeSpec, ...] = NODES
    links: tuple[tuple[str, str, float, str], ...] = LINKS
    sources: tuple[SourceSpec, ...] = SOURCES
    displacement: dict[str, dict[str, float]] = field(default_factory=lambda: {
        k: dict(v) for k, v in DISPLACEMENT.items()})
    pump_heat_w: float = PUMP_HEAT_W
    pump_table_w_per_k: float = PUMP_TABLE_W_PER_K

    def __post_init__(self) -> None:
        names = [n.name for n in self.nodes]
        idx = {n: i for i, n in enumerate(names)}
        g = np.zeros((len(names), len(names)))
        for a, b, w, _ in self.links:
            if a not in idx or b not in idx:
                raise InputError(f"link {a}-{b}: unknown node")
            g[idx[a], idx[b]] += w
            g[idx[b], idx[a]] += w
        self.network = ThermalNetwork(names, np.array([n.capacity_j_per_k for n in self.nodes]),
                                      g)
        for s in self.sources:
            if s.node not in idx:
                raise InputError(f"heat source on unknown node '{s.node}'")
        for axis, coefs in self.displacement.items():
            for node in coefs:
                if node not in idx or not self.nodes[idx[node]].measured:
                    raise InputError(f"{axis}: displacement coefficient on '{node}', which is "
                                     "not a measured node (hidden nodes belong to effects)")

    @property
    def names(self) -> list[str]:
        return self.network.names

    @property
    def measured(self) -> list[str]:
        return [n.name for n in self.nodes if n.measured]

    def heat_w(self, s: float) -> np.ndarray:
        """Heat generated in each node at speed fraction s (W)."""
        q = np.zeros(self.network.n)
        if s > 0:
            for src in self.sources:
                q[self.network.index(src.node)] += src.watts_at_max * s ** src.exponent
        return q

    def to_ambient_w_per_k(self, s: float) -> np.ndarray:
        return np.array([n.to_ambient_w_per_k * (1.0 + n.speed_gain * s) for n in self.nodes])

    def operating_point(self, s: float, pump_on: bool = False) -> OperatingPoint:
        """Inputs at speed fraction s, with the coolant pump on or off."""
        heat = self.heat_w(s)
        extra = None
        if pump_on:
            i, j = self.network.index("table"), self.network.index("tank")
            heat[j] += self.pump_heat_w
            extra = np.zeros((self.network.n, self.network.n))
            extra[i, j] = extra[j, i] = self.pump_table_w_per_k
        return OperatingPoint(self.to_ambient_w_per_k(s), heat, extra)

    def coefficient_matrix(self, axes: tuple[str, ...] = AXES) -> np.ndarray:
        """(n_nodes, n_axes) um/K of each node's rise, measured nodes only."""
        m = np.zeros((self.network.n, len(axes)))
        for k, axis in enumerate(axes):
            for node, c in self.displacement.get(axis, {}).items():
                m[self.network.index(node), k] = c
        return m
