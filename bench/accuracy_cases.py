"""One case of the accuracy bench as its JSON keeps it (bench/results/accuracy.json): every
column's test error (the columns: OURS and PEERS), the promise, the peers; shared by the bench
(bench.bench_accuracy), its figure (bench.accuracy_figure) and the comparisons, so none of them
imports another."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from thermal_comp.contract.box import BOX_CHANNELS

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "accuracy.json"
PEERS = ("OLS all", "top-4 |r|", "SFS-4", "SFS-5", "LassoCV", "best-4", "best-5",
         "ridge+lags", "lasso+lags", "HGB")
# ours, one column per way of training: "undeclared" is the default without the job's bending
# axes (the comparison for the declaration; where a job declares none it is the default itself,
# not trained twice); "no prefilter" is the default with its ridge fitted to the raw rows
# (host.fitting.prefilter)
OURS = {"default": {}, "no effects": {"effects": False}, "paper": {"selection": "paper"},
        "undeclared": {}, "no prefilter": {"prefilter_s": 0.0}}
CALIBRATION_FACTOR = 2.0  # a promise "holds within 2x" in the calibration table


@dataclass
class CaseResult:
    source: str
    group: str
    test: str
    target: str
    reference: str
    # the job's training data (Job.group): every case of one job shares its models, so the
    # intervals resample whole training sets (clustered_interval)
    training_set: str = ""
    rmse_um: dict[str, float] = field(default_factory=dict)  # column -> test RMSE
    promised_um: dict[str, float] = field(default_factory=dict)  # ours -> promised RMSE
    # ours -> the highest nested fold, the top of the promise's spread (highest_fold)
    highest_fold_um: dict[str, float] = field(default_factory=dict)
    validation_um: dict[str, float] = field(default_factory=dict)  # ours -> validation RMSE
    n_terms: dict[str, int] = field(default_factory=dict)  # ours -> terms on this axis
    raw_um: float = math.nan  # scored error of predicting zero change
    # sim_dev only: its manifest's scores of the test run ("oracle": least squares on the true
    # node temperatures and effect term, the floor a model could reach; "oracle without
    # hidden": on the measurable nodes and the air only; "noise floor")
    floor_um: dict[str, float] = field(default_factory=dict)
    peer_sensors: dict[str, int] = field(default_factory=dict)  # peer -> sensors it reads
    # peer -> its out-of-fold RMSE on the training file (peer_validation)
    peer_validation_um: dict[str, float] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    effects: dict[str, list[str]] = field(default_factory=dict)  # ours -> effects it kept

    @property
    def cluster(self) -> str:
        """The unit the intervals resample: the training set (a JSON written before the
        bench recorded it falls back to the case's group, one per variant)."""
        return self.training_set or self.group

    @property
    def best_peer(self) -> tuple[str, float]:
        scored = [(p, self.rmse_um[p]) for p in PEERS
                  if p in self.rmse_um and not math.isnan(self.rmse_um[p])]
        return min(scored, key=lambda kv: kv[1]) if scored else ("", math.nan)

    @property
    def best_box_peer(self) -> tuple[str, float]:
        """The best peer the box could run: at most BOX_CHANNELS thermocouples."""
        scored = [(p, self.rmse_um[p]) for p in PEERS
                  if p in self.rmse_um and not math.isnan(self.rmse_um[p])
                  and self.peer_sensors.get(p, BOX_CHANNELS + 1) <= BOX_CHANNELS]
        return min(scored, key=lambda kv: kv[1]) if scored else ("", math.nan)

    @property
    def validated_peer(self) -> tuple[str, float]:
        """The peer with the lowest out-of-fold error on the training file, and its test
        RMSE: the one a user would pick without seeing the test run."""
        scored = [(p, self.peer_validation_um[p]) for p in PEERS
                  if math.isfinite(self.peer_validation_um.get(p, math.nan))
                  and math.isfinite(self.rmse_um.get(p, math.nan))]
        if not scored:
            return ("", math.nan)
        name = min(scored, key=lambda kv: kv[1])[0]
        return name, self.rmse_um[name]

    def ratio(self, column: str = "default") -> float:
        return self.rmse_um.get(column, math.nan) / self.best_peer[1]

    def validated_ratio(self, column: str = "default") -> float:
        return self.rmse_um.get(column, math.nan) / self.validated_peer[1]

    def box_ratio(self, column: str = "default") -> float:
        return self.rmse_um.get(column, math.nan) / self.best_box_peer[1]
