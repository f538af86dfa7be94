"""The simulator of a vertical machining center, and the thermal test program (NC) that drives it.
"""

from __future__ import annotations

from thermal_comp.host.sim.machine_model import AXES, LINKS, NODES, SOURCES, Machine
from thermal_comp.host.sim.simulator import (
    EFFECTS,
    RPM_COLUMN,
    SimConfig,
    SimulationError,
    load_truth,
    parse_effects,
    simulate,
    simulate_nodes,
    truth_path,
    write_simulation,
)
from thermal_comp.host.sim.spindle_programs import COOL, PROTOCOLS, RUN, ProgramError, build_program
from thermal_comp.host.sim.testplan import DIALECTS, PlanError, ThermalTestPlan, parse_duration
from thermal_comp.host.sim.thermal_network import OperatingPoint, ThermalNetwork

__all__ = [
    "AXES",
    "COOL",
    "DIALECTS",
    "EFFECTS",
    "LINKS",
    "Machine",
    "NODES",
    "OperatingPoint",
    "PROTOCOLS",
    "PlanError",
    "ProgramError",
    "RPM_COLUMN",
    "RUN",
    "SOURCES",
    "SimConfig",
    "SimulationError",
    "ThermalNetwork",
    "ThermalTestPlan",
    "build_program",
    "load_truth",
    "parse_duration",
    "parse_effects",
    "simulate",
    "simulate_nodes",
    "truth_path",
    "write_simulation",
]
