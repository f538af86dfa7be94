"""The accuracy bench's cases: which runs each source trains on and tests on (``Job``), and
where they come from. One home for the sources' data, seeds, targets and declared bending, so
the bench, its quick variant and the other benches that reuse its splits agree."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bench.accuracy_cases import ROOT

SHARED = Path(os.environ.get("THERMAL_SHARED_DATA", ROOT.parent / "shared" / "data"))
SIM_DEV = SHARED / "sim_dev"
FL_STEPS = SHARED / "fl_thermal" / "steps.csv"

SOURCES = ("sim", "sim_dev", "fl", "fl_next", "sim_other")
SIM_SEEDS = (0, 1, 2)
# not used to choose the defaults (bench_selection compares selections on 0-4; 3-8 were
# consulted for variants not taken, docs/lab/next-day.md)
OTHER_SIM_SEEDS = (3, 4, 5, 6, 7, 8)
SIM_EFFECTS = ("lag", "ambient", "speed")
FL_PROBES = [f"ch{i}_um" for i in range(1, 6)]
FL_CYCLE_S = 8 * 3600.0
DEV_TARGETS = ["dy_um", "dz_um"]
SIM_TARGETS = ["dx_um", "dy_um", "dz_um"]
AUX = ["spindle_rpm"]
# the simulators' axis a column's front/back difference bends (Y of a vertical machining
# center: sim_dev's README, "+ toward the column"; host.sim's column_front/column_back); FL's
# probe directions are not documented, so it declares none
BENDING = ("dy_um",)
BENDING_SOURCES = ("sim", "sim_dev", "sim_other")


def declared_bending(source: str) -> tuple[str, ...]:
    """The axes a source's jobs declare bending (train_model(bending=)): one home for it."""
    return BENDING if source in BENDING_SOURCES else ()


@dataclass(frozen=True)
class RunSpec:
    """A run to load: a CSV path and optionally a time window [start_s, stop_s)."""

    path: str
    start_s: float | None = None
    stop_s: float | None = None
    label: str = ""

    @property
    def name(self) -> str:
        return self.label or Path(self.path).stem


@dataclass(frozen=True)
class Job:
    """One training set with its test runs: trains every column once per job."""

    source: str  # one of SOURCES
    group: str  # e.g. "machine11 S1", "S0 LORO machine12: P3 held out", "FL cycle 2 out"
    train: tuple[RunSpec, ...]
    test: tuple[RunSpec, ...]
    targets: tuple[str, ...]
    reference: str  # "start" or "none"
    # (case group, one model per target?) per way of training ours on this data; the peers
    # are fitted once and shared (FL: one probe per model, and all five probes on one box)
    variants: tuple[tuple[str, bool], ...] = ()
    bending: tuple[str, ...] = ()  # train_model(bending=): what the user knows of the axes

    def ours_variants(self) -> tuple[tuple[str, bool], ...]:
        return self.variants or ((self.group, False),)


def sim_jobs(tmp: Path, seeds: Sequence[int] = SIM_SEEDS, source: str = "sim") -> list[Job]:
    """The project's simulator: write the runs of machines ``seeds`` into ``tmp`` (seconds),
    one job per machine, under ``source``."""
    from thermal_comp.host.sim import SimConfig, build_program, simulate, write_simulation

    jobs = []
    days = (("constant", 0, 8.0, 20.0), ("step", 1, 8.0, 20.0),
            ("random", 100, 13.0, 21.5), ("sine", 101, 6.0, 22.0))
    for m in seeds:
        specs = []
        for protocol, offset, start_hour, ambient in days:
            seed = 1000 * m + offset
            program = build_program(protocol, hours=8.0, cool_hours=8.0, seed=seed)
            sim = simulate(program, SimConfig(seed=seed, machine_seed=m, effects=SIM_EFFECTS,
                                              start_hour=start_hour, ambient_c=ambient))
            path = tmp / f"sim_m{m}_{protocol}.csv"
            write_simulation(sim, path)
            specs.append(RunSpec(str(path), label=protocol))
        jobs.append(Job(source, f"machine {m}", tuple(specs[:2]), tuple(specs[2:]),
                        tuple(SIM_TARGETS), "start", bending=declared_bending(source)))
    return jobs


def manifest_floor(test_path: str, target: str) -> dict[str, float]:
    """The sim_dev manifest's oracle and noise floor for one test run and axis (its README:
    "use the oracle as the floor"); empty where the manifest scores no such run (a training
    run held out by leave-one-run-out) or the file is not a sim_dev run."""
    path = Path(test_path)
    manifest = path.parent / "manifest.json"
    if not manifest.is_file():
        return {}
    axis = target.removesuffix("_um")
    for scenario in json.loads(manifest.read_text()).get("scenarios", []):
        scores = scenario.get("rmse_um", {}).get(path.name, {}).get(axis)
        if scores:
            out = {"oracle": float(scores["oracle"]), "noise floor": float(scores["noise_floor"])}
            if "oracle_without_hidden" in scores:
                out["oracle without hidden"] = float(scores["oracle_without_hidden"])
            return out
    return {}


def dev_jobs(big: bool = True) -> list[Job]:
    jobs = []
    for machine in sorted(p for p in SIM_DEV.glob("machine*") if p.is_dir()):
        files = sorted(machine.glob("*.csv"))
        scenarios = sorted({f.name.split("_train_")[0] for f in files if "_train_" in f.name})
        for sc in scenarios:
            if sc.startswith("S0_64") and not big:
                continue
            train = [f for f in files if f.name.startswith(f"{sc}_train_")]
            test = [f for f in files if f.name.startswith(f"{sc}_test_")]
            jobs.append(Job("sim_dev", f"{machine.name} {sc}",
                            tuple(RunSpec(str(f)) for f in train),
                            tuple(RunSpec(str(f)) for f in test), tuple(DEV_TARGETS), "start",
                            bending=declared_bending("sim_dev")))
        days = [f for f in files if f.name.startswith("S0_") and not f.name.startswith("S0_64")]
        for held in days:
            jobs.append(Job("sim_dev", f"{machine.name} S0 LORO",
                            tuple(RunSpec(str(f)) for f in days if f != held),
                            (RunSpec(str(held)),), tuple(DEV_TARGETS), "start",
                            bending=declared_bending("sim_dev")))
    return jobs


def fl_next_jobs() -> list[Job]:
    """FL_THERMAL the way a shop would use it: the recording so far as one training run, the
    next 8 h cycle (faster and hotter than any before it) as the unseen day. Trained on
    cycles 1-2, tested on 3; on 1-3, tested on 4 (the demo's split)."""
    jobs = []
    for k in (2, 3):
        train = RunSpec(str(FL_STEPS), None, k * FL_CYCLE_S, f"cycles 1-{k}")
        test = RunSpec(str(FL_STEPS), k * FL_CYCLE_S, (k + 1) * FL_CYCLE_S if k < 3 else None,
                       f"cycle {k + 1}")
        jobs.append(Job("fl_next", f"FL cycles 1-{k}, next", (train,), (test,),
                        tuple(FL_PROBES), "none",
                        ((f"FL next, one probe, cycles 1-{k}", True),
                         (f"FL next, 5 probes, cycles 1-{k}", False))))
    return jobs


def fl_jobs() -> list[Job]:
    cuts: list[float | None] = [None, FL_CYCLE_S, 2 * FL_CYCLE_S, 3 * FL_CYCLE_S, None]
    cycles = [RunSpec(str(FL_STEPS), cuts[i], cuts[i + 1], f"cycle {i + 1}") for i in range(4)]
    jobs = []
    for i, held in enumerate(cycles):
        train = tuple(c for j, c in enumerate(cycles) if j != i)
        jobs.append(Job("fl", f"FL cycle {i + 1} out", train, (held,), tuple(FL_PROBES), "none",
                        ((f"FL one probe, cycle {i + 1} out", True),
                         (f"FL 5 probes, cycle {i + 1} out", False))))
    return jobs


