"""What decides a simulated run besides the spindle program: ``SimConfig`` and the effects.

``EFFECT_DEFAULTS`` documents every effect's parameters (docs/simulator.md); a run's
``SimConfig.effect_params`` overrides them. ``random_stream`` gives each purpose (shop air,
sensor noise, gauge noise, pump, weather) its own seeded stream.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from thermal_comp.contract.errors import InputError

EFFECTS = ("lag", "ambient", "speed", "drift", "coolant", "nonlinear")
RPM_COLUMN = "spindle_rpm"
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


def random_stream(seed: int, stream: int) -> np.random.Generator:
    """Independent stream per purpose, so switching one effect never reshuffles another's noise."""
    return np.random.default_rng([seed, stream])
