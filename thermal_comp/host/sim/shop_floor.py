"""The shop around the machine: the air (slow wander, and the day's cycle with the ``ambient``
effect) and the unlogged coolant pump of the ``coolant`` effect.
"""

from __future__ import annotations

import math

import numpy as np

from thermal_comp.host.sim.run_config import SimConfig, random_stream


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
        self.wander = _ou_knots(random_stream(config.seed, 2), n, self.KNOT_S, config.wander_sd_c,
                                config.wander_tau_s)
        self.start_hour = config.start_hour
        self.daily: dict | None = None
        self.weather = np.zeros(n)
        if "ambient" in config.effects:
            d = config.params("ambient")
            rng = random_stream(config.seed, 6)
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
    rng = random_stream(config.seed, 5)
    out = []
    t = float(rng.uniform(0, p["off_min"])) * 60.0
    while t < duration_s:
        on = max(1.0, p["on_min"] + rng.uniform(-p["jitter_min"], p["jitter_min"])) * 60.0
        off = max(1.0, p["off_min"] + rng.uniform(-p["jitter_min"], p["jitter_min"])) * 60.0
        out.append((t, min(t + on, duration_s)))
        t += on + off
    return out
