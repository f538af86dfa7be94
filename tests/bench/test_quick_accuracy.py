"""One column of ours against a saved accuracy bench (bench/quick_accuracy.py): the peers come
from the saved bench, our other columns and the promises do not, a case the saved bench lacks
is refused by name, and the cases that moved are listed, the largest first."""

import pytest

from bench import bench_accuracy as acc
from bench import quick_accuracy as quick


def saved_case(test: str, ours: float) -> acc.CaseResult:
    c = acc.CaseResult("sim_dev", "machine11 S0", test, "dy_um", "start", "machine11 S0")
    c.rmse_um = {"default": ours, "no effects": 9.0, "OLS all": 2.0, "lasso+lags": 1.0}
    c.promised_um = {"default": 0.5}
    c.effects = {"default": ["lag(T01, 7200 s)"]}
    return c


def key(test: str) -> tuple[str, str, str, str]:
    return ("sim_dev", "machine11 S0", test, "dy_um")


def test_merged_keeps_the_saved_peers_and_only_the_new_column():
    saved = {key(t): saved_case(t, 1.5) for t in ("P3", "P5")}
    out = {c.test: c for c in quick.merged(saved, {key("P3"): 0.8, key("P5"): 3.0}, "default")}
    assert out["P3"].rmse_um == {"OLS all": 2.0, "lasso+lags": 1.0, "default": 0.8}
    assert out["P5"].rmse_um["default"] == 3.0
    assert out["P3"].best_peer == ("lasso+lags", 1.0)
    assert out["P3"].promised_um == {} and out["P3"].effects == {}  # trained without nesting
    assert saved[key("P3")].rmse_um["default"] == 1.5  # the saved bench is left as it was


def test_a_case_the_saved_bench_lacks_is_refused_by_name():
    saved = {key("P3"): saved_case("P3", 1.0)}
    with pytest.raises(SystemExit, match="P9"):
        quick.merged(saved, {key("P9"): 1.0}, "default")


def test_moved_most_lists_the_largest_ratios_first_and_says_when_none_moved():
    before = {key(t): saved_case(t, 1.0) for t in ("P1", "P2", "P3")}
    after = {k: c for k, c in zip(before, quick.merged(
        before, {key("P1"): 1.0, key("P2"): 0.5, key("P3"): 1.5}, "default"), strict=True)}
    text = quick.moved_most(before, after, "default").splitlines()
    assert text[1:] == ["  sim_dev / machine11 S0 / P2 / dy_um: 1.000 -> 0.500",
                        "  sim_dev / machine11 S0 / P3 / dy_um: 1.000 -> 1.500"]
    same = dict(zip(before, quick.merged(before, {k: 1.0 for k in before}, "default"),
                    strict=True))
    assert quick.moved_most(before, same, "default") == "no case's default moved"


def test_the_shipped_baseline_holds_the_peers_and_the_default_column_of_every_source():
    # `python -m bench.quick_accuracy` on a fresh clone compares against this file
    # (bench/results/ is not in git): every source, the ten peers and our default column
    from bench import compare_accuracy as cmp

    saved = cmp.load(quick.BASELINE)
    assert {k[0] for k in saved} == set(acc.SOURCES)
    for case in saved.values():
        assert "default" in case.rmse_um
        assert set(acc.PEERS) <= set(case.rmse_um)
        assert case.training_set  # the intervals resample whole training sets
