"""Simulated runs: each effect does what its truth file says (and nothing when off), the run is
reproducible by seed, round-trips through the loader, and the effects are material: the
matching candidate term cuts the held-out error of a static model of all the thermocouples."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_comp.contract.terms import make_lag, make_square, make_time
from thermal_comp.host.fitting import fit_linear, rmse, term_values
from thermal_comp.host.io import load_run
from thermal_comp.host.sim import (
    EFFECTS,
    SimConfig,
    SimulationError,
    build_program,
    parse_effects,
    simulate,
    truth_path,
    write_simulation,
)

AXES = ("dx_um", "dy_um", "dz_um")
DT = 60.0


def run(protocol="step", effects=(), seed=5, hours=6.0, cool=4.0, n_sensors=12, **kw):
    prog = build_program(protocol, 8000.0, hours, cool, seed=seed)
    return simulate(prog, SimConfig(n_sensors=n_sensors, dt_s=DT, seed=seed,
                                    effects=tuple(effects), **kw))


@pytest.fixture(scope="module")
def plain():
    return run()


@pytest.mark.parametrize("effect", ["lag", "speed", "nonlinear"])
def test_displacement_only_effects_add_exactly_their_truth_component(plain, effect):
    sim = run(effects=[effect])
    p = sim.truth["effects"][effect]
    # same physics, same noise: temperatures are untouched
    for name in plain.sensor_names:
        np.testing.assert_array_equal(sim.columns[name], plain.columns[name])
    rpm = sim.columns["spindle_rpm"]
    for axis in AXES:
        diff = sim.columns[axis] - plain.columns[axis]
        if effect == "speed":
            expected = p["coef_um_at_max"].get(axis, 0.0) * (rpm / 8000.0) ** 2
        elif effect == "lag":
            node = np.array(sim.truth["nodes_c"]["shaft"])
            expected = p["coef_um_per_k"].get(axis, 0.0) * (node - node[0])
        else:
            node = np.array(sim.truth["nodes_c"][p["node"]])
            expected = p["coef_um_per_k2"].get(axis, 0.0) * (node - p["reference_c"]) ** 2
        np.testing.assert_allclose(diff, expected, atol=5e-3)  # truth stored to 1e-3
        if axis in sim.truth["components_um"][effect]:
            assert np.ptp(expected) > 5.0  # material: several um
        else:
            np.testing.assert_array_equal(diff, 0.0)  # off on that axis: not at all


def test_speed_effect_has_no_lag():
    sim = run(effects=["speed"])
    comp = np.array(sim.truth["components_um"]["speed"]["dz_um"])
    rpm = sim.columns["spindle_rpm"]
    change = np.flatnonzero(np.diff(rpm) != 0) + 1
    # the component jumps in the very sample the speed changes
    assert np.all(np.abs(np.diff(comp)[change - 1]) > 0.1)
    assert np.all(np.abs(np.diff(comp)[np.diff(rpm) == 0]) < 1e-9)


def test_shaft_is_unmeasured_and_lags_the_bearings(plain):
    assert all(s.node != "shaft" and s.neighbour != "shaft" for s in plain.sensors)
    shaft, bearing = plain.node("shaft"), plain.node("bearing_front")
    peak_shaft, peak_bearing = np.argmax(shaft), np.argmax(bearing)
    assert peak_shaft > peak_bearing  # peaks later: pseudo-hysteresis


def test_drift_moves_only_the_named_sensor_by_its_rate(plain):
    sim = run(effects=["drift"])
    p = sim.truth["effects"]["drift"]
    assert sim.truth["sensors"][p["sensor"]]["node"] == "column_front"
    for name in plain.sensor_names:
        diff = sim.columns[name] - plain.columns[name]
        if name == p["sensor"]:
            expected = p["rate_c_per_h"] * sim.time_s / 3600.0
            assert np.max(np.abs(diff - expected)) <= 0.0078125 + 1e-9  # one LSB of rounding
            assert expected[-1] > 1.0
        else:
            np.testing.assert_array_equal(diff, 0.0)
    for axis in AXES:
        np.testing.assert_array_equal(sim.columns[axis], plain.columns[axis])


def test_ambient_effect_adds_a_day_to_the_air_and_a_lagged_frame_term(plain):
    sim = run(effects=["ambient"], hours=8, cool=8)
    p = sim.truth["effects"]["ambient"]
    air = sim.columns["T_amb"] - run(hours=8, cool=8).columns["T_amb"]
    assert np.ptp(air) > 1.0  # the day's cycle is in the measured air
    core = np.array(sim.truth["nodes_c"]["frame_core"])
    comp = np.array(sim.truth["components_um"]["ambient"]["dz_um"])
    np.testing.assert_allclose(comp, p["coef_um_per_k"]["dz_um"] * (core - core[0]), atol=5e-3)
    assert np.ptp(comp) > 5.0
    # the frame core is a first-order lag of the air with the stated time constant
    alpha = -np.expm1(-DT / p["node_tau_s"])
    lag = term_values(make_lag("a", p["node_tau_s"], DT), {"a": sim.columns["T_amb"]}, DT)
    assert np.corrcoef(lag, core)[0, 1] > 0.98 and 0 < alpha < 1


def test_coolant_effect_cycles_the_table_with_the_unlogged_pump(plain):
    sim = run(effects=["coolant"])
    p = sim.truth["effects"]["coolant"]
    assert len(p["schedule_s"]) >= 5
    table = sim.columns[p["matching_terms"][0]["source"]]
    on = np.zeros(sim.time_s.size, bool)
    for a, b in p["schedule_s"]:
        on |= (sim.time_s > a) & (sim.time_s <= b)
    rate = np.diff(table)
    assert rate[on[1:]].mean() > 0 > rate[~on[1:]].mean()  # warm coolant on, cools off
    body = np.array(sim.truth["nodes_c"]["table_body"])
    comp = np.array(sim.truth["components_um"]["coolant"]["dz_um"])
    np.testing.assert_allclose(comp, p["coef_um_per_k"]["dz_um"] * (body - body[0]), atol=5e-3)
    assert "spindle_rpm" in sim.columns and "pump" not in " ".join(sim.columns)


def test_same_seed_same_run_other_seed_other_noise():
    a, b, c = run(seed=3), run(seed=3), run(seed=4)
    for name in a.columns:
        np.testing.assert_array_equal(a.columns[name], b.columns[name])
    assert a.truth == b.truth
    assert not np.array_equal(a.columns["T01"], c.columns["T01"])


def test_csv_round_trip_through_the_loader(tmp_path):
    sim = run(effects=["speed", "drift"], n_sensors=20)
    path = tmp_path / "sim.csv"
    tp = write_simulation(sim, path)
    assert tp == truth_path(path) == tmp_path / "sim.truth.json"
    loaded = load_run(path, list(AXES), sensors="T*", aux=["spindle_rpm"])
    assert loaded.sensor_names == [f"T{i:02d}" for i in range(1, 21)] + ["T_amb"]
    for i, name in enumerate(loaded.sensor_names):
        np.testing.assert_allclose(loaded.temperatures[:, i], sim.columns[name], atol=1e-4)
    np.testing.assert_allclose(loaded.displacements, np.column_stack(
        [sim.columns[a] for a in AXES]), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(loaded.aux[:, 0], sim.columns["spindle_rpm"])
    assert loaded.period_s == DT
    truth = json.loads(tp.read_text())
    assert truth["n_samples"] == loaded.n_samples
    assert len(truth["displacement_true_um"]["dz_um"]) == loaded.n_samples
    # quantised to the MAX31856 step (before the CSV's 6 significant digits)
    q = sim.columns["T05"] / 0.0078125
    np.testing.assert_allclose(q, np.round(q), atol=1e-9)


def test_sixty_four_sensors_have_near_duplicates():
    sim = run(n_sensors=64, hours=2, cool=1)
    names = [s.name for s in sim.sensors]
    assert names[0] == "T01" and names[-1] == "T64" and "T_amb" in sim.columns
    x = np.column_stack([sim.columns[n] for n in names])
    r = np.corrcoef(x.T)
    np.fill_diagonal(r, 0)
    assert (r > 0.999).sum() > 20  # multicollinearity, as with real thermocouple arrays


def test_bad_requests_are_refused():
    with pytest.raises(SimulationError, match="unknown effect 'laag'"):
        parse_effects("lag,laag")
    assert parse_effects("all") == EFFECTS
    with pytest.raises(SimulationError, match="--dt"):
        simulate(build_program("constant", hours=1, cool_hours=0), SimConfig(dt_s=-1.0))
    with pytest.raises(ValueError, match="--sensors"):
        run(n_sensors=0)


def _feature(sim, term):
    kind = term["kind"]
    if kind == "temp":
        return sim.columns[term["source"]]
    if kind == "lag":
        t = make_lag(term["source"], term["tau_s"], DT)
    elif kind == "square":
        t = make_square(term["source"], term["ref_c"])
    elif kind == "time":
        t = make_time()
    else:  # speed2
        return sim.columns[term["source"]] ** 2
    return term_values(t, sim.columns, DT)


def _heldout_rmse(train, test, axis, extra):
    names = train.sensor_names
    have = set(names)
    extra = [e for e in extra if not (e["kind"] == "temp" and e["source"] in have)]

    def design(sim):
        return np.column_stack([sim.columns[n] for n in names]
                               + [_feature(sim, e) for e in extra])

    fit = fit_linear(design(train), train.columns[axis])
    return rmse(fit.predict(design(test)) - test.columns[axis])


@pytest.mark.parametrize("effect, axis", [("lag", "dz_um"), ("ambient", "dz_um"),
                                          ("speed", "dz_um"), ("drift", "dy_um"),
                                          ("coolant", "dz_um"), ("nonlinear", "dy_um")])
def test_matching_term_cuts_heldout_error_of_a_static_model_of_every_sensor(effect, axis):
    train = run("step", [effect], seed=11, hours=8, cool=8)
    test = run("random", [effect], seed=22, hours=8, cool=8)
    static = _heldout_rmse(train, test, axis, [])
    matched = _heldout_rmse(train, test, axis, train.truth["effects"][effect]["matching_terms"])
    assert matched <= 0.6 * static, (static, matched)


def test_without_effects_a_static_model_is_at_the_noise_floor():
    train, test = run("step", seed=11, hours=8, cool=8), run("random", seed=22, hours=8, cool=8)
    for axis in AXES:
        err = _heldout_rmse(train, test, axis, [])
        assert err < 0.03 * np.ptp(test.displacement_true[axis]), axis


def test_every_node_link_and_effect_is_documented():
    from pathlib import Path

    from thermal_comp.host.sim import LINKS, NODES, SOURCES

    doc = (Path(__file__).parents[3] / "docs" / "simulator.md").read_text()
    for node in NODES:
        assert f"`{node.name}`" in doc, node.name
        assert f"| {node.capacity_j_per_k / 1e3:g} |" in doc, node.name  # its capacity
    for a, b, _g, _ in LINKS:
        assert f"`{a}` – `{b}`" in doc or f"`{a}` – `tank`" in doc, (a, b)
    for src in SOURCES:
        assert f"{src.watts_at_max:g} s" in doc, src
    for effect in EFFECTS:
        assert f"| `{effect}` |" in doc, effect
