"""The thermal network's physics against analytic answers: energy balance, RC time constants,
monotone heating, relaxation, and the exact propagator against scipy's matrix exponential."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from thermal_comp.host.sim import (
    LINKS,
    NODES,
    SOURCES,
    Machine,
    OperatingPoint,
    ThermalNetwork,
    build_program,
    simulate_nodes,
)

T_AMB = 20.0


def constant_air(t):
    return np.full(np.shape(t), T_AMB)


def test_single_node_reaches_one_time_constant_at_rc():
    c, g, q = 1000.0, 2.0, 10.0  # tau = C/g = 500 s, rise Q/g = 5 K
    net = ThermalNetwork(["lump"], np.array([c]), np.zeros((1, 1)))
    op = OperatingPoint(np.array([g]), np.array([q]))
    assert net.time_constants_s(op)[0] == pytest.approx(c / g)
    x = np.array([T_AMB])
    step = net.step(op, 50.0)
    for _ in range(10):  # 10 x 50 s = one time constant
        x = step.phi @ x + step.gamma_amb * T_AMB + step.gamma_q
    assert x[0] - T_AMB == pytest.approx(q / g * (1 - math.exp(-1)), rel=1e-12)


def test_two_node_modes_match_the_analytic_eigenvalues():
    c1, c2, g12, g2 = 500.0, 4000.0, 3.0, 1.5
    net = ThermalNetwork(["a", "b"], np.array([c1, c2]), np.array([[0, g12], [g12, 0]]))
    op = OperatingPoint(np.array([0.0, g2]), np.zeros(2))
    a = np.array([[-g12 / c1, g12 / c1], [g12 / c2, -(g12 + g2) / c2]])
    tr, det = np.trace(a), np.linalg.det(a)
    lam = np.array([(tr + s * math.sqrt(tr * tr - 4 * det)) / 2 for s in (1, -1)])
    np.testing.assert_allclose(net.time_constants_s(op), -1 / lam, rtol=1e-10)


@pytest.mark.parametrize("speed, pump", [(0.0, False), (0.75, False), (1.0, True)])
def test_modal_propagator_equals_scipy_expm(speed, pump):
    m = Machine()
    op = m.operating_point(speed, pump)
    n = m.network.n
    # reference built here from the ODE, independently of ThermalNetwork
    cap = np.array([nd.capacity_j_per_k for nd in NODES])
    g = np.zeros((n, n))
    for a, b, w, _ in LINKS:
        i, j = m.names.index(a), m.names.index(b)
        g[i, j] += w
        g[j, i] += w
    if pump:
        i, j = m.names.index("table"), m.names.index("tank")
        g[i, j] += m.pump_table_w_per_k
        g[j, i] += m.pump_table_w_per_k
    a_mat = (g - np.diag(g.sum(1) + op.to_ambient)) / cap[:, None]
    aug = np.zeros((n + 2, n + 2))
    aug[:n, :n] = a_mat
    aug[:n, n] = op.to_ambient / cap
    aug[:n, n + 1] = op.heat / cap
    for h in (1.0, 60.0, 7200.0):
        e = expm(aug * h)
        step = m.network.step(op, h)
        np.testing.assert_allclose(step.phi, e[:n, :n], atol=1e-12)
        np.testing.assert_allclose(step.gamma_amb, e[:n, n], atol=1e-12)
        np.testing.assert_allclose(step.gamma_q, e[:n, n + 1], atol=1e-9)


def test_steady_state_energy_balance_within_0_1_percent():
    m = Machine()
    s = 0.75
    # long enough for the slowest mode (~20 h) to die out completely
    prog = build_program("constant", 8000.0, hours=600.0, cool_hours=0.0)
    t = np.arange(0, 600 * 3600 + 1, 3600.0)
    temps = simulate_nodes(m, prog, t, constant_air)[-1]
    heat_in = sum(src.watts_at_max * s ** src.exponent for src in SOURCES)
    g_out = np.array([nd.to_ambient_w_per_k * (1 + nd.speed_gain * s) for nd in NODES])
    heat_out = float(np.sum(g_out * (temps - T_AMB)))
    assert heat_out == pytest.approx(heat_in, rel=1e-3)
    # and the simulated end state is the network's steady state
    np.testing.assert_allclose(temps, m.network.steady_state(T_AMB, m.operating_point(s)),
                               atol=1e-6)


def test_constant_heating_raises_every_node_monotonically_then_relaxes_to_ambient():
    m = Machine()
    prog = build_program("constant", 8000.0, hours=8.0, cool_hours=300.0)
    t = np.arange(0, prog.duration_s + 1, 600.0)
    temps = simulate_nodes(m, prog, t, constant_air)
    heating = temps[t <= 8 * 3600]
    assert np.all(np.diff(heating, axis=0) >= -1e-12)
    rises = heating[-1] - T_AMB
    for name in ("bearing_front", "motor", "gearbox", "headstock"):
        assert 5.0 <= rises[m.names.index(name)] <= 25.0, name  # 5-20 K class rises
    assert np.all(np.abs(temps[-1] - T_AMB) < 1e-3)


def test_time_constants_span_minutes_to_hours():
    taus = Machine().network.time_constants_s(Machine().operating_point(0.75))
    assert taus.min() < 10 * 60  # bearings: minutes
    assert taus.max() > 5 * 3600  # base: hours


def test_network_rejects_bad_parameters():
    with pytest.raises(ValueError, match="capacity"):
        ThermalNetwork(["a"], np.array([0.0]), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="symmetric"):
        ThermalNetwork(["a", "b"], np.ones(2), np.array([[0, 1.0], [2.0, 0]]))
    net = ThermalNetwork(["a"], np.array([1.0]), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="no path to ambient"):
        net.step(OperatingPoint(np.zeros(1), np.zeros(1)), 1.0)


def test_result_does_not_depend_on_the_step_when_inputs_change_between_samples():
    # segment and pump switchings fall between samples of the coarse grid: the interval is
    # split at them, so 7 s and 1 s sampling agree at common times (constant air: exact)
    m = Machine()
    prog = build_program("random", 8000.0, hours=1.5, cool_hours=0.5, seed=2)
    pump = [(100.5, 1000.25), (2000.0, 2333.3)]
    fine_t = np.arange(0, 7 * 1000 + 1, 1.0)
    coarse_t = np.arange(0, 7 * 1000 + 1, 7.0)
    fine = simulate_nodes(m, prog, fine_t, constant_air, pump)
    coarse = simulate_nodes(m, prog, coarse_t, constant_air, pump)
    np.testing.assert_allclose(coarse, fine[::7], atol=1e-9)
    assert np.ptp(fine[:, m.names.index("table")]) > 0.3  # the pump did something
