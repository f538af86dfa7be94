"""Paper 000, section 2.2 (Figs. 1-2): a heated bar shows why the delay tau matters.

A 0.5 m steel bar (section 8e-5 m^2) is heated at x = 0 by 20 W for 30 min, then 40 W for
30 min, then left to cool; 11 sensors sit every 5 cm from the source to the free end, and the
free-end displacement is alpha * integral of the temperature rise (eq. 3). The bar is solved
here with explicit finite volumes (conduction along the bar, convection from its surface), so
the expectations come from the physics, not from host.selection.correlation. The paper reports that
sensors further from the source lag more (and are smoothed), and that the free-end
displacement *leads* the distant sensors because it integrates the whole bar.

The paper gives only the geometry; with textbook steel (k = 50 W/m K) and still-air convection
the source end rises far more than its Fig. 2 (about 1000 K instead of 80-120 K). The test
checks the shapes the argument rests on (order of peaks and delays), not the magnitudes.
"""

from __future__ import annotations

import numpy as np
import pytest

from thermal_comp.host.selection import thermal_parameters

LENGTH_M = 0.5
AREA_M2 = 8e-5
PERIMETER_M = 0.036  # 8 mm x 10 mm section
K_W_MK = 50.0  # steel
RHO_C = 7850.0 * 460.0  # J/(m^3 K)
H_W_M2K = 10.0  # still-air convection
EXPANSION_PER_K = 11.5e-6
DX_M = 0.01
DT_S = 1.0
SAMPLE_S = 30.0
HOURS = 5.0


def simulate_bar() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample times, 11 sensor rises (K) and the free-end displacement (um)."""
    n = int(round(LENGTH_M / DX_M)) + 1
    diffusivity = K_W_MK / RHO_C
    assert DT_S <= 0.4 * DX_M ** 2 / diffusivity  # explicit scheme stable
    volume = np.full(n, AREA_M2 * DX_M)
    volume[[0, -1]] /= 2
    surface = np.full(n, PERIMETER_M * DX_M)
    surface[[0, -1]] /= 2
    theta = np.zeros(n)  # rise above ambient
    conductance = K_W_MK * AREA_M2 / DX_M
    steps = int(HOURS * 3600 / DT_S)
    every = int(SAMPLE_S / DT_S)
    times, rises = [], []
    for step in range(steps + 1):
        t = step * DT_S
        if step % every == 0:
            times.append(t)
            rises.append(theta.copy())
        power = 20.0 if t < 1800 else 40.0 if t < 3600 else 0.0
        flow = np.zeros(n)
        flow[:-1] += conductance * (theta[1:] - theta[:-1])
        flow[1:] += conductance * (theta[:-1] - theta[1:])
        flow -= H_W_M2K * surface * theta
        flow[0] += power
        theta = theta + DT_S * flow / (RHO_C * volume)
    rises = np.array(rises)
    x = np.linspace(0, LENGTH_M, n)
    displacement_um = EXPANSION_PER_K * np.trapezoid(rises, x, axis=1) * 1e6
    sensors = rises[:, ::5]  # x = 0, 0.05, ..., 0.5 m
    return np.array(times), sensors, displacement_um


@pytest.fixture(scope="module")
def bar():
    return simulate_bar()


def test_bar_heats_and_cools_as_described(bar):
    t, T, d = bar
    assert T.shape[1] == 11
    # the source sensor jumps with each heat step and falls when the heat is switched off
    at = {m: int(np.searchsorted(t, m * 60)) for m in (30, 60, 90)}
    assert T[at[30], 0] > 0 and T[at[60], 0] > T[at[30], 0] > 0
    assert T[at[90], 0] < T[at[60], 0]
    # far sensors are smoothed: smaller and later peaks
    peaks = T.max(axis=0)
    assert np.all(np.diff(peaks) < 0)


def test_delay_grows_with_distance_and_displacement_leads_far_sensors(bar):
    t, T, d = bar
    # physics, independently of host.selection.correlation: peak times grow with distance and the
    # displacement peaks before the far half of the bar does
    peak_t = t[np.argmax(T, axis=0)]
    assert np.all(np.diff(peak_t) >= 0) and peak_t[-1] > peak_t[1]
    assert t[np.argmax(d)] < peak_t[5]
    # the method's tau (positive = the temperature lags the displacement) says the same
    params = thermal_parameters([(T, d)], period_s=SAMPLE_S, max_lag_s=2 * 3600)
    tau = params.delays_s
    assert np.all(np.diff(tau) >= 0), tau
    assert tau[-1] > tau[1]
    assert tau[0] < 0  # the source leads the displacement
    assert np.all(tau[5:] > 0)  # the displacement leads the distant sensors
    # and the sign of tau agrees with the order of the peaks
    lead = peak_t - t[np.argmax(d)]
    assert np.all(np.sign(tau[5:]) == np.sign(lead[5:]))
