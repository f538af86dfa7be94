"""Issue 7 on simulated data: `host simulate` injects one effect, nothing tells `host train`
which, and the model is judged on another run with a different speed profile.

Train: the ``step`` protocol (6 h running, 4 h cooling, 60 s); judge: the ``random`` protocol
of another seed (another day: other shop air, other noise). The baseline is the same
`host train` with ``--no-effects``. Expectations come from the simulator's truth sidecar
(which effect, which sensor drifts, which sensor sits on the table) and from numpy.

Most scenarios train dy and dz together. The ``ambient`` and ``coolant`` scenarios train dz
alone, the only axis those effects move (docs/simulator.md): two axes of five sensors each
fill the box's eight thermocouple channels, and host.train then keeps the effect search to
sensors that already have a channel, which shuts out the air sensor T_amb. That would test
the channel budget, not the effect search (docs/effects.md, "Results").
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from thermal_comp.contract.terms import Term
from thermal_comp.host.cli import main
from thermal_comp.host.effects import state_quantisation_um
from thermal_comp.host.fitting import design_matrix
from thermal_comp.host.io import load_run
from thermal_comp.host.sim import load_truth

TRAIN = ["--protocol", "step", "--hours", "6", "--cool-hours", "4", "--dt", "60"]
TEST = ["--protocol", "random", "--hours", "6", "--cool-hours", "4", "--dt", "60"]
TARGETS = ["--target", "dy_um", "--target", "dz_um", "--aux", "spindle_rpm"]
DZ_ONLY = ["--target", "dz_um", "--aux", "spindle_rpm"]
SINGLE_AXIS = {"ambient", "coolant"}  # effects that move dz only, trained on dz alone


def host(*args: str) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([*args])
    assert code == 0, out.getvalue()
    return out.getvalue()


class Scenario:
    """One simulated effect: the training and the judging run, both models, the truth."""

    def __init__(self, root: Path, effect: str, seed: int, small: bool = False) -> None:
        d = root / f"{effect}_{seed}{'_small' if small else ''}"
        d.mkdir()
        train_effects = "" if effect in ("none", "drift") else effect  # drift: test run only
        test_effects = "" if effect == "none" else effect
        size = ["--hours", "3", "--cool-hours", "2"] if small else []
        self.train_csv, self.test_csv = d / "train.csv", d / "test.csv"
        host("simulate", *TRAIN, *size, "--seed", str(seed), "--effects", train_effects,
             "-o", str(self.train_csv))
        host("simulate", *TEST, *size, "--seed", str(seed + 100), "--effects", test_effects,
             "-o", str(self.test_csv))
        self.truth = load_truth(self.test_csv)
        targets = DZ_ONLY if effect in SINGLE_AXIS else TARGETS
        # absolute values (reference none): these cases test the search on the effects' shapes
        host("train",
             "--fit", "ols", "--no-nested",
             str(self.train_csv), *targets, "--no-effects", "--no-codegen",
             "--reference", "none",
             "--out", str(d / "baseline"))
        # with effects, codegen runs too: train fails if the box could not run the model
        self.summary = json.loads(host("train", "--fit", "ols", "--no-nested",
                                       str(self.train_csv), *targets, "--json",
                                       "--reference", "none",
                                       "--out", str(d / "effects")))
        self.baseline = json.loads((d / "baseline" / "model.json").read_text())
        self.model = json.loads((d / "effects" / "model.json").read_text())
        self.header = d / "effects" / "model.h"
        self.test = load_run(self.test_csv, ["dy_um", "dz_um"], "T*", ["spindle_rpm"])

    def held_out(self, model: dict, axis: str) -> float:
        spec = model["axes"][axis]
        terms = [Term.from_json(t) for t in spec["terms"]]
        coefs = np.array([t["coef"] for t in spec["terms"]])
        pred = design_matrix(terms, self.test.columns(), model["sample_period_s"]) @ coefs
        return float(np.sqrt(np.mean((self.test.target(axis) - pred - spec["intercept"]) ** 2)))

    def kinds(self, axis: str) -> list[str]:
        return [e["kind"] for e in self.model["axes"][axis]["effects"]]


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    root = tmp_path_factory.mktemp("effects_sim")
    made: dict = {}

    def get(effect: str, seed: int = 0, small: bool = False) -> Scenario:
        key = (effect, seed, small)
        if key not in made:
            made[key] = Scenario(root, effect, seed, small)
        return made[key]

    return get


# The axis each effect moves most (simulator defaults, docs/simulator.md); the issue asks for
# the requirement on every scenario, so ambient and speed are held to it on three days each.
@pytest.mark.parametrize("effect,seed,axis,kinds", [
    ("lag", 0, "dz_um", {"lag", "rate"}),
    ("speed", 0, "dz_um", {"speed"}),
    ("speed", 1, "dz_um", {"speed"}),
    ("speed", 2, "dz_um", {"speed"}),
    ("nonlinear", 0, "dy_um", {"nonlinear"}),
    ("ambient", 0, "dz_um", {"ambient"}),
    ("ambient", 1, "dz_um", {"ambient"}),
    ("ambient", 2, "dz_um", {"ambient"}),
])
def test_injected_effect_is_named_and_held_out_error_drops(scenario, effect, seed, axis, kinds):
    s = scenario(effect, seed)
    assert set(s.kinds(axis)) & kinds, s.model["axes"][axis]["effects"]
    before, after = s.held_out(s.baseline, axis), s.held_out(s.model, axis)
    assert after <= 0.6 * before, (before, after)
    # the --json summary carries the shape
    doc = s.summary["axes"][axis]
    assert doc["baseline_validation_rmse_um"] > doc["validation_rmse_um"]
    first = doc["effects"][0]
    assert {"kind", "feature", "evidence", "rmse_before_um", "rmse_after_um"} <= set(first)
    assert first["evidence"]["folds_improved"].endswith("/3")
    assert s.header.is_file()  # codegen accepted the model with its effects


def test_speed_effect_wires_the_aux_input(scenario):
    s = scenario("speed")
    used = {t["source"] for a in s.model["axes"].values() for t in a["terms"]
            if t["kind"] in ("speed", "speed2")}
    assert used == {"spindle_rpm"}
    assert [a["name"] for a in s.model["aux"]] == ["spindle_rpm"]
    assert "#define TCM_N_AUX 1u" in s.header.read_text()


@pytest.mark.parametrize("effect", ["lag", "speed", "nonlinear"])
def test_codegen_bound_holds_and_matches_the_filter_state_estimate(scenario, effect):
    s = scenario(effect)
    for axis, spec in s.model["axes"].items():
        fp = s.model["fixed_point"]["axes"][axis]
        assert fp["bound_um"] <= 0.01
        terms = [Term.from_json(t) for t in spec["terms"]]
        mine = state_quantisation_um(terms, [t["coef"] for t in spec["terms"]])
        assert fp["state_quantisation_um"] == pytest.approx(mine, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("effect,seed", [("ambient", 0), ("ambient", 1), ("ambient", 2),
                                         ("speed", 1)])
def test_input_effect_replaces_the_stand_in_sensors(scenario, effect, seed):
    """The air and the spindle speed reach the whole machine, so the static selection picks
    thermocouples that stand in for them; the input's family comes with the sensors selected
    again, and what the model keeps is the input's own term (the truth's matching term for the
    air: its lag at the frame's time constant) instead of stand-ins for it."""
    s = scenario(effect, seed)
    spec = s.model["axes"]["dz_um"]
    first = spec["effects"][0]
    assert first["kind"] == effect and first.get("reselected") is True
    ev = first["evidence"]
    # the input itself must beat the re-selected sensors alone by the same rule
    assert ev["improvement_over_sensors_only_pct"] >= 10.0
    assert ev["folds_improved_over_sensors_only"] in ("2/3", "3/3")
    final = {(t["kind"], t["source"]) for t in spec["terms"]}
    if effect == "ambient":
        truth = s.truth["effects"]["ambient"]["matching_terms"]
        lag = next(m for m in truth if m["kind"] == "lag")
        taus = [t["tau_s"] for t in spec["terms"] if t["kind"] == "lag"
                and t["source"] == lag["source"]]
        assert taus and min(abs(math.log(t / lag["tau_s"])) for t in taus) < math.log(2)
    else:
        assert ("speed2", "spindle_rpm") in final


def test_no_effect_nothing_added_on_eight_of_ten_seeds(scenario):
    added = []
    for seed in range(10):
        s = scenario("none", seed, small=True)
        added.append(bool(s.model["axes"]["dz_um"]["effects"]))
    assert sum(added) <= 2, added


def test_coolant_is_unexplained_or_names_the_table_and_claims_no_large_gain(scenario):
    s = scenario("coolant")
    axis = "dz_um"
    spec = s.model["axes"][axis]
    table = {t["source"] for t in s.truth["effects"]["coolant"]["matching_terms"]}
    named = {t.get("source") for e in spec["effects"] for t in e["added"]}
    assert spec["unexplained"] is not None or named & table
    claimed = 1 - spec["validation_rmse_um"] / spec["baseline_validation_rmse_um"]
    assert claimed < 0.4
    assert s.held_out(s.model, axis) <= 1.1 * s.held_out(s.baseline, axis)


def test_diagnose_names_the_drifting_sensor(scenario):
    s = scenario("drift")
    sensor = s.truth["effects"]["drift"]["sensor"]
    assert sensor in [c["sensor"] for c in s.model["channels"]]
    doc = json.loads(host("diagnose", str(s.header.parent / "model.json"), str(s.test_csv),
                          "--json"))
    assert [(f["sensor"], f["fault"]) for f in doc["faulty"]] == [(sensor, "drifting")]
    hours = (s.test.time_s[-1] - s.test.time_s[0]) / 3600
    rate = s.truth["effects"]["drift"]["rate_c_per_h"]
    assert doc["sensors"][sensor]["evidence"]["drift_c"] == pytest.approx(rate * hours, rel=0.3)
    # the model's error on the drifting run is explained by a slow trend, not by the machine
    assert doc["axes"]["dz_um"]["explained_by"][0]["kind"] == "drift"
    assert doc["axes"]["dz_um"]["rmse_um"] > 5 * s.model["axes"]["dz_um"]["metrics"][
        "validation_rmse_um"]


@pytest.mark.parametrize("effect", ["lag", "speed", "nonlinear", "coolant"])
def test_diagnose_accuses_no_healthy_sensor(scenario, effect):
    """Not with ``ambient``: there the other day's shop air moves the slow tank sensor (T11)
    away from the column sensors it tracked in training, by as much as a drift (a known
    limit of a one-run reference, docs/effects.md)."""
    s = scenario(effect)
    doc = json.loads(host("diagnose", str(s.header.parent / "model.json"), str(s.test_csv),
                          "--json"))
    assert doc["faulty"] == []
    assert set(doc["axes"]) == set(s.model["axes"])


def test_the_ridge_leaves_slow_lag_effects_to_its_own_lags(scenario, tmp_path):
    """The default fit, a ridge over lags of every sensor it reads, keeps a lag or rate
    effect's own filter only when it is faster than the ridge's fastest lag; a slower one is
    named, its sensor read, and the ridge's lags of that sensor stand for it, unless the box's
    ridge is not 10 % lower with the effects at all (then it runs without them, saying so)."""
    s = scenario("lag")
    out = tmp_path / "ridge"
    host("train", "--no-nested", str(s.train_csv), *TARGETS, "--reference", "none",
         "--no-codegen", "--out", str(out))
    model = json.loads((out / "model.json").read_text())
    slow = 0
    for spec in model["axes"].values():
        terms = [Term.from_json(t) for t in spec["terms"]]
        kept = spec["fit"]["family"] == "ridge"
        if not kept:  # the box's own ridge did not gain from the effects: none of them runs
            assert spec["fit"]["family"] == "ridge-baseline"
            assert spec["effects"] and all(e["dropped_by_box_ridge"] for e in spec["effects"])
            assert "out of fold with them" in spec["effects_rejected"]
        for effect in spec["effects"]:
            if effect["kind"] not in ("lag", "rate"):
                continue
            own = [Term.from_json(t) for t in effect["added"] if t["kind"] in ("lag", "rate")]
            taus = {t.params["tau_s"] for t in own}
            if min(taus) >= 900.0:
                slow += 1
            if not kept:
                assert "in_ridge_lags" not in effect
            elif min(taus) >= 900.0 and not all(t in terms for t in own):
                lags = [t.name for t in terms if t.kind == "lag"
                        and t.source in {o.source for o in own}]
                assert lags and effect["in_ridge_lags"] == lags
                assert {o.source for o in own} <= {t.source for t in terms}
            else:
                assert "in_ridge_lags" not in effect and all(t in terms for t in own)
    assert slow >= 1  # the search names at least one lag slower than 900 s on this run


def test_a_slow_lag_effect_is_marked_as_the_ridges_own_lags():
    """mark_lags_in_basis: a lag effect whose filter is not in the ridge's basis names the
    ridge's lags of its sensor that stand for it; one whose filter the box runs is left as is."""
    from thermal_comp.host.train.next_day_fit import mark_lags_in_basis

    slow = Term("lag", "T03", {"tau_s": 7200.0})
    fast = Term("lag", "T05", {"tau_s": 300.0})
    basis = [Term("temp", "T03"), Term("lag", "T03", {"tau_s": 900.0}),
             Term("lag", "T03", {"tau_s": 3600.0}), Term("temp", "T05"), fast]
    axis = {"effects": [{"kind": "lag", "added": [slow.to_json()]},
                        {"kind": "lag", "added": [fast.to_json()]}]}
    mark_lags_in_basis(axis, basis)
    assert axis["effects"][0]["in_ridge_lags"] == [basis[1].name, basis[2].name]
    assert "in_ridge_lags" not in axis["effects"][1]
