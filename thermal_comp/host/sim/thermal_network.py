"""A lumped-capacitance thermal network and its exact discretisation.

Each node i has a heat capacity C_i (J/K); nodes exchange heat through conductances G_ij (W/K),
lose it to the ambient air through g_i (W/K) and receive heat Q_i (W):

    C_i dT_i/dt = sum_j G_ij (T_j - T_i) + g_i (T_amb - T_i) + Q_i

For inputs held constant over a step of length h (the operating point: g, Q and extra
conductances depend on spindle speed and on the coolant pump), the exact solution is

    T(t + h) = Phi T(t) + gamma_amb T_amb + gamma_q,   [Phi gamma] = expm([[A, B], [0, 0]] h)

so a simulation is a chain of matrix-vector products, exact for piecewise-constant inputs
whatever the step: no stability limit, no integration error (the ambient air is held at its
mid-step value, an O(h^2) approximation of a smooth profile).

The matrix exponential is computed from the symmetric eigen-decomposition of
C^-1/2 K C^-1/2 (K = conduction Laplacian + convection, symmetric positive definite), which
is exact and, once per operating point, makes every step length cheap; ``step_expm`` is the
same propagator through scipy.linalg.expm, kept as the reference the tests compare against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.errors import InputError


@dataclass(frozen=True)
class OperatingPoint:
    """Inputs held constant over a piece of time."""

    to_ambient: np.ndarray  # g_i, W/K
    heat: np.ndarray  # Q_i, W
    extra_conductance: np.ndarray | None = None  # symmetric (n, n) W/K added to the network


@dataclass(frozen=True)
class StepOperator:
    """Exact propagator of one operating point over one step length."""

    phi: np.ndarray  # (n, n)
    gamma_amb: np.ndarray  # (n,)
    gamma_q: np.ndarray  # (n,)


class ThermalNetwork:
    """Nodes with capacities joined by symmetric conductances."""

    def __init__(self, names: list[str], capacity_j_per_k: np.ndarray,
                 conductance_w_per_k: np.ndarray) -> None:
        c = np.asarray(capacity_j_per_k, dtype=float)
        g = np.asarray(conductance_w_per_k, dtype=float)
        n = len(names)
        if c.shape != (n,) or g.shape != (n, n):
            raise InputError(f"network of {n} nodes needs {n} capacities and an {n}x{n} "
                             f"conductance matrix (got {c.shape}, {g.shape})")
        if np.any(c <= 0):
            raise InputError(f"node '{names[int(np.argmin(c))]}' has a non-positive capacity")
        if not np.allclose(g, g.T) or np.any(g < 0) or np.any(np.diag(g) != 0):
            raise InputError("conductances must be symmetric, non-negative, zero on the diagonal")
        self.names = list(names)
        self.capacity = c
        self.conductance = g

    @property
    def n(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def stiffness(self, op: OperatingPoint) -> np.ndarray:
        """K = Laplacian(G) + diag(g): heat flow out of each node per kelvin (W/K)."""
        g = self.conductance if op.extra_conductance is None else (
            self.conductance + op.extra_conductance)
        return np.diag(g.sum(axis=1) + op.to_ambient) - g

    def derivative(self, temps: np.ndarray, t_amb: float, op: OperatingPoint) -> np.ndarray:
        """dT/dt in K/s (used by tests and for documentation; simulation uses step())."""
        flow = -self.stiffness(op) @ temps + op.to_ambient * t_amb + op.heat
        return flow / self.capacity

    def steady_state(self, t_amb: float, op: OperatingPoint) -> np.ndarray:
        """Temperatures where heat in equals heat out (requires a path to ambient)."""
        return np.linalg.solve(self.stiffness(op), op.to_ambient * t_amb + op.heat)

    def time_constants_s(self, op: OperatingPoint) -> np.ndarray:
        """Time constants of the network's modes, slowest first (1 / eigenvalues of C^-1 K)."""
        s = 1.0 / np.sqrt(self.capacity)
        sym = s[:, None] * self.stiffness(op) * s[None, :]  # similar to C^-1 K, symmetric
        return np.sort(1.0 / np.linalg.eigvalsh(sym))[::-1]

    def modes(self, op: OperatingPoint) -> Modes:
        """Eigen-decomposition of the operating point (decay rates and mode shapes)."""
        s = 1.0 / np.sqrt(self.capacity)
        rates, v = np.linalg.eigh(s[:, None] * self.stiffness(op) * s[None, :])
        if rates[0] <= 0:
            raise InputError("the network has no path to ambient: temperatures never settle")
        left = s[:, None] * v  # S V
        right = v.T / s[None, :]  # V^T S^-1
        drive = v.T @ (s * np.column_stack([op.to_ambient, op.heat]).T).T  # V^T S b
        return Modes(rates, left, right, drive)

    def step(self, op: OperatingPoint, h: float) -> StepOperator:
        """Exact propagator over h seconds with the inputs of ``op`` held constant."""
        return self.modes(op).step(h)

    def step_expm(self, op: OperatingPoint, h: float) -> StepOperator:
        """The same propagator through scipy.linalg.expm of the augmented matrix (reference)."""
        from scipy.linalg import expm

        n = self.n
        a = -self.stiffness(op) / self.capacity[:, None]
        m = np.zeros((n + 2, n + 2))
        m[:n, :n] = a
        m[:n, n] = op.to_ambient / self.capacity
        m[:n, n + 1] = op.heat / self.capacity
        e = expm(m * h)
        return StepOperator(e[:n, :n].copy(), e[:n, n].copy(), e[:n, n + 1].copy())


@dataclass(frozen=True)
class Modes:
    """A = -C^-1 K = -(S V) diag(rates) (V^T S^-1), S = C^-1/2; exact steps of any length."""

    rates: np.ndarray  # 1/s, ascending
    left: np.ndarray  # S V
    right: np.ndarray  # V^T S^-1
    drive: np.ndarray  # (n, 2): V^T S [g, Q]

    def step(self, h: float) -> StepOperator:
        decay = np.exp(-self.rates * h)
        gain = -np.expm1(-self.rates * h) / self.rates  # integral of exp(-rate*t) over [0, h]
        phi = (self.left * decay[None, :]) @ self.right
        gamma = self.left @ (gain[:, None] * self.drive)
        return StepOperator(phi, gamma[:, 0].copy(), gamma[:, 1].copy())
