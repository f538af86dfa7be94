"""Per-axis estimators of what the model misses, updated by probe readings (float reference).

Each estimator holds a correction that adds to the model's output. Between readings its
state propagates in time (its variance grows with the process noise ``q`` per hour); at a
reading it sees the innovation, reading - (model output + current correction) at that sample,
and, when the gate accepts it, updates. A reading at sample k changes the output from sample
k + 1 on (the box answers MEAS after it has output sample k).

- ``BiasKalman`` (the default, docs/service.md): a scalar Kalman filter on a bias that walks
  randomly (variance q per hour), probe noise R. Its variance starts at ``p0_um2`` (0 for a
  ``start`` model: at ZERO the bias is zero by definition; ``p_max_um2`` for ``none``) and is
  capped by ``p_max_um2``.
- ``BiasRateKalman``: bias and its rate (a constant-velocity Kalman filter, the rate walking
  with ``q / 1 h^2``); the correction between readings extrapolates the rate.
- ``DiscountedBias``: exponential smoothing of the innovation with a fixed gain ``alpha``
  (a Kalman filter frozen at one gain), gated with the same bookkeeping of P.
- ``BiasGainKalman``: a bias and a correction of the model's gain (the correction is
  b + s * model output), or, with ``regressor="rate"``, of its timing (b + s * the model's
  rate over the last 15 min: a time shift of its curve). Measured, not the default
  (docs/service.md): it pays on FL_THERMAL and costs on both simulators.

Every estimator sees a regressor per sample (``regressor``: zeros for the bias kinds), so the
correction may follow the model's output between readings.

``run_estimator`` runs one over a run, with the gate and its re-opening (``reopen_after``
refused readings in a row that agree: the model, not the probe, is off; docs/service.md);
``ESTIMATORS`` names them for the bench.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from thermal_comp.contract.service import INNOVATION_MAX_NM, NM_PER_UM
from thermal_comp.host.service.gate import Gate
from thermal_comp.host.service.parameters import ServiceParams


class Estimator:
    """The interface: reset, propagate by dt hours, the correction dt hours ahead (``g``: the
    regressor at those samples), the variance of the current correction at a sample of
    regressor ``g``, and an update by an accepted innovation."""

    def regressor(self, prediction: np.ndarray, time_s: np.ndarray) -> np.ndarray:
        """What the correction may scale per sample (none for a bias)."""
        return np.zeros_like(prediction)

    def reset(self) -> None:
        raise NotImplementedError

    def propagate(self, dt_h: float) -> None:
        raise NotImplementedError

    def offset(self, dt_h: np.ndarray, g: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def variance(self, g: float = 0.0) -> float:
        raise NotImplementedError

    def update(self, innovation: float, r: float, g: float = 0.0) -> None:
        raise NotImplementedError

    def reopen(self, innovation: float, r: float) -> None:
        """The gate's lock-out ended: the estimate takes the reading as it is, with the
        reading's variance (capped as the estimate's)."""
        raise NotImplementedError


class BiasKalman(Estimator):
    """Scalar Kalman filter on a random-walk bias."""

    def __init__(self, q_um2_per_h: float, p_max_um2: float, p0_um2: float | None = None
                 ) -> None:
        self.q, self.p_max = q_um2_per_h, p_max_um2
        self.p0 = p_max_um2 if p0_um2 is None else min(p0_um2, p_max_um2)
        self.reset()

    def reset(self) -> None:
        self.b, self.p = 0.0, self.p0

    def propagate(self, dt_h: float) -> None:
        self.p = min(self.p + self.q * dt_h, self.p_max)

    def offset(self, dt_h: np.ndarray, g: np.ndarray) -> np.ndarray:
        return np.full(np.shape(dt_h), self.b)

    def variance(self, g: float = 0.0) -> float:
        return self.p

    def update(self, innovation: float, r: float, g: float = 0.0) -> None:
        k = self.p / (self.p + r)
        self.b += k * innovation
        self.p = (1.0 - k) * self.p

    def reopen(self, innovation: float, r: float) -> None:
        self.b += innovation
        self.p = min(r, self.p_max)


class BiasRateKalman(Estimator):
    """Bias and rate (um/h), a constant-velocity Kalman filter."""

    def __init__(self, q_um2_per_h: float, p_max_um2: float, p0_um2: float | None = None,
                 q_rate: float | None = None) -> None:
        self.q, self.p_max = q_um2_per_h, p_max_um2
        self.p0 = p_max_um2 if p0_um2 is None else min(p0_um2, p_max_um2)
        self.q_rate = q_um2_per_h if q_rate is None else q_rate  # (um/h)^2 per hour
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(2)
        # the rate a priori: what the bias could reach in an hour at the cap
        self.P = np.diag([self.p0, self.p_max])

    def propagate(self, dt_h: float) -> None:
        F = np.array([[1.0, dt_h], [0.0, 1.0]])
        qr = self.q_rate
        Q = np.array([[self.q * dt_h + qr * dt_h ** 3 / 3, qr * dt_h ** 2 / 2],
                      [qr * dt_h ** 2 / 2, qr * dt_h]])
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q
        if self.P[0, 0] > self.p_max:  # the same cap as the bias alone, both states scaled
            self.P *= self.p_max / self.P[0, 0]

    def offset(self, dt_h: np.ndarray, g: np.ndarray) -> np.ndarray:
        return self.x[0] + self.x[1] * np.asarray(dt_h, dtype=float)

    def variance(self, g: float = 0.0) -> float:
        return float(self.P[0, 0])

    def update(self, innovation: float, r: float, g: float = 0.0) -> None:
        s = self.P[0, 0] + r
        k = self.P[:, 0] / s
        self.x = self.x + k * innovation
        self.P = self.P - np.outer(k, self.P[0, :])

    def reopen(self, innovation: float, r: float) -> None:
        self.x = self.x + np.array([innovation, 0.0])
        self.P = np.diag([min(r, self.p_max), self.p_max])


class DiscountedBias(BiasKalman):
    """b += alpha * innovation: a fixed gain; P (propagated as the Kalman's) is kept only for
    the gate."""

    def __init__(self, q_um2_per_h: float, p_max_um2: float, p0_um2: float | None = None,
                 alpha: float = 0.7) -> None:
        self.alpha = alpha
        super().__init__(q_um2_per_h, p_max_um2, p0_um2)

    def update(self, innovation: float, r: float, g: float = 0.0) -> None:
        self.b += self.alpha * innovation
        self.p = (1.0 - self.alpha) ** 2 * self.p + self.alpha ** 2 * r


RATE_WINDOW_S = 900.0  # the model's rate for the timing correction: its change over 15 min


class BiasGainKalman(Estimator):
    """x = [b, s], correction b + s * g, g the model's output (``"gain"``: its gain is off by
    s) or its rate in um/h (``"rate"``: its curve is late by s hours). s starts at 0 with
    standard deviation ``s_sd`` and walks with ``q_s`` per hour, capped at ``s_sd``."""

    def __init__(self, q_um2_per_h: float, p_max_um2: float, p0_um2: float | None = None,
                 regressor: str = "gain", s_sd: float = 0.05, q_s: float = 0.01) -> None:
        self.q, self.p_max = q_um2_per_h, p_max_um2
        self.p0 = p_max_um2 if p0_um2 is None else min(p0_um2, p_max_um2)
        self.kind, self.s_var, self.q_s = regressor, s_sd ** 2, q_s
        self.reset()

    def regressor(self, prediction: np.ndarray, time_s: np.ndarray) -> np.ndarray:
        m = np.asarray(prediction, dtype=float)
        if self.kind == "gain":
            return m
        t_h = (np.asarray(time_s, dtype=float) - float(time_s[0])) / 3600.0
        n = max(1, round(RATE_WINDOW_S / max(float(np.median(np.diff(time_s))), 1e-9)))
        rate = np.zeros_like(m)
        rate[n:] = (m[n:] - m[:-n]) / (t_h[n:] - t_h[:-n])
        return rate

    def reset(self) -> None:
        self.x = np.zeros(2)
        self.P = np.diag([self.p0, self.s_var])

    def propagate(self, dt_h: float) -> None:
        self.P = self.P + np.diag([self.q * dt_h, self.q_s * dt_h])
        self.P[0, 0] = min(self.P[0, 0], self.p_max)
        self.P[1, 1] = min(self.P[1, 1], self.s_var)

    def offset(self, dt_h: np.ndarray, g: np.ndarray) -> np.ndarray:
        return self.x[0] + self.x[1] * np.asarray(g, dtype=float)

    def variance(self, g: float = 0.0) -> float:
        h = np.array([1.0, g])
        return float(h @ self.P @ h)

    def update(self, innovation: float, r: float, g: float = 0.0) -> None:
        h = np.array([1.0, g])
        k = self.P @ h / (float(h @ self.P @ h) + r)
        self.x = self.x + k * innovation
        self.P = self.P - np.outer(k, h @ self.P)

    def reopen(self, innovation: float, r: float) -> None:
        self.x = self.x + np.array([innovation, 0.0])
        self.P = np.diag([min(r, self.p_max), self.P[1, 1]])


ESTIMATORS: dict[str, Callable[[ServiceParams], Estimator]] = {
    "bias": lambda p: BiasKalman(p.q_um2_per_h, p.p_max_um2, p.p0_um2),
    "bias+rate": lambda p: BiasRateKalman(p.q_um2_per_h, p.p_max_um2, p.p0_um2),
    "discounted": lambda p: DiscountedBias(p.q_um2_per_h, p.p_max_um2, p.p0_um2),
    "bias+gain": lambda p: BiasGainKalman(p.q_um2_per_h, p.p_max_um2, p.p0_um2, "gain"),
    "bias+timing": lambda p: BiasGainKalman(p.q_um2_per_h, p.p_max_um2, p.p0_um2, "rate",
                                            s_sd=0.1),
}
DEFAULT_ESTIMATOR = "bias"


@dataclass
class ServiceTrace:
    """What an estimator did over a run: the correction added at every sample, and per
    reading its sample, innovation, whether the gate accepted it and whether that reading
    re-opened the axis (accepted after ``reopen_after`` agreeing refusals)."""

    correction: np.ndarray
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    innovation: np.ndarray = field(default_factory=lambda: np.zeros(0))
    accepted: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    reopened: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def refused(self) -> int:
        return int(np.count_nonzero(~self.accepted))


@dataclass
class Reopening:
    """The gate's lock-out rule (docs/service.md, "Re-opening"): refused readings in a row
    whose innovations agree with the streak's first (their difference passes the gate) count;
    at ``after`` of them (0: never) the estimate takes the reading as it is."""

    after: int = 0
    streak: int = 0
    anchor: float = 0.0

    def refused(self, gate: Gate, nu: float, variance: float) -> bool:
        """A reading the gate refused: True when it re-opens the axis."""
        if not self.after or abs(nu) * NM_PER_UM > INNOVATION_MAX_NM:
            self.streak = 0
            return False
        if self.streak and gate.accepts(nu - self.anchor, variance):
            self.streak += 1
        else:
            self.streak, self.anchor = 1, nu
        if self.streak < self.after:
            return False
        self.streak = 0
        return True


def run_estimator(est: Estimator, gate: Gate, r_um2: float, prediction: np.ndarray,
                  time_s: np.ndarray, index: np.ndarray, value: np.ndarray,
                  reopen_after: int = 0) -> ServiceTrace:
    """Run ``est`` over one run: ``prediction`` is the model's output (referenced as the box
    outputs it), readings ``value`` at samples ``index`` (increasing); ``reopen_after``:
    agreeing refusals in a row that re-open the axis (0: never)."""
    prediction = np.asarray(prediction, dtype=float)
    g = est.regressor(prediction, np.asarray(time_s, dtype=float))
    t_h = (np.asarray(time_s, dtype=float) - float(time_s[0])) / 3600.0
    n = prediction.size
    est.reset()
    rule = Reopening(int(reopen_after))
    corr = np.zeros(n)
    t_state, start = 0.0, 0
    nus, oks, reopens = [], [], []
    order = np.argsort(index, kind="stable")
    for k, z in zip(np.asarray(index)[order], np.asarray(value, dtype=float)[order],
                    strict=True):
        k = int(k)
        corr[start:k + 1] = est.offset(t_h[start:k + 1] - t_state, g[start:k + 1])
        est.propagate(t_h[k] - t_state)
        t_state = t_h[k]
        nu = float(z - (prediction[k] + est.offset(np.zeros(1), g[k:k + 1])[0]))
        v = est.variance(float(g[k])) + r_um2
        ok = gate.accepts(nu, v)
        reopen = not ok and rule.refused(gate, nu, v)
        if reopen:
            est.reopen(nu, r_um2)
        if ok:
            rule.streak = 0
            est.update(nu, r_um2, float(g[k]))
        nus.append(nu)
        oks.append(ok or reopen)
        reopens.append(reopen)
        start = max(start, k + 1)
    corr[start:] = est.offset(t_h[start:] - t_state, g[start:])
    return ServiceTrace(corr, np.asarray(index)[order].astype(int), np.asarray(nus, dtype=float),
                        np.asarray(oks, dtype=bool), np.asarray(reopens, dtype=bool))
