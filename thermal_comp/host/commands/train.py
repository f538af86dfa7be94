"""`host train RUN.csv [RUN2.csv ...] --target dz_um`: select sensors, fit, validate, write
DIR/model.json and (by default) DIR/model.h."""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from thermal_comp.contract.box import BOX_STATES
from thermal_comp.contract.errors import InputError
from thermal_comp.contract.model_file import jsonable, write_model, write_text_atomic
from thermal_comp.contract.terms import FILTER_KINDS, Term, filter_states
from thermal_comp.contract.tilt import Tilt, unit_of
from thermal_comp.host.commands._arguments import add_reference_argument, seed_arg
from thermal_comp.host.commands._options import add_fill_gaps, csv_format
from thermal_comp.host.io import load_runs
from thermal_comp.host.selection import METHODS
from thermal_comp.host.train import (
    FITS,
    dropped_reason,
    ridge_lags_note,
    summary,
    train_model,
)
from thermal_comp.host.train.nested import promise_rule
from thermal_comp.host.train.options import TC_TYPES, TrainOptions
from thermal_comp.host.train.service_refit import load_service_logs, refit_on_probes

NAME = "train"
HELP = "select sensors (paper 000), fit and validate the thermal model; write model.json"


def parse_channel(text: str) -> tuple[str, int]:
    name, sep, ch = text.partition("=")
    if not sep or not name or not ch.strip().isdigit():
        raise argparse.ArgumentTypeError(f"--channel expects SENSOR=INDEX (e.g. T38=0), got "
                                         f"{text!r}")
    return name.strip(), int(ch)


def parse_tilt(text: str) -> Tilt:
    try:
        return Tilt.parse(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_data_arguments(parser: argparse.ArgumentParser, tilts: bool = False) -> None:
    """Column roles shared by train and compare (``tilts``: also ``--tilt``)."""
    parser.add_argument("--target", action="append", required=not tilts, default=[],
                        metavar="COL",
                        help="displacement column to model (repeat for several axes)")
    if tilts:
        parser.add_argument("--tilt", action="append", type=parse_tilt, default=[],
                            metavar="NAME=UPPER,LOWER,DISTANCE_MM",
                            help="a tilt axis in urad from two gap probes DISTANCE_MM apart on "
                                 "the test bar: (UPPER - LOWER) * 1000 / DISTANCE_MM, positive "
                                 "when the upper probe reads more; NAME ends in _urad "
                                 "(repeatable; paper 002's five-probe setup)")
    parser.add_argument("--bending", action="append", default=[], metavar="AXIS",
                        help="a target that a temperature difference across the structure "
                             "moves, not an even warming (a column bent by its front against "
                             "its back: Y of a vertical machining center); its ridge then "
                             "penalises the response to an even warming (repeatable; "
                             "docs/training.md)")
    parser.add_argument("--sensors", default=TrainOptions.sensors, metavar="GLOB",
                        help="temperature columns (glob, default %(default)s)")
    parser.add_argument("--aux", action="append", default=[], metavar="COL",
                        help="auxiliary input column, e.g. spindle_rpm (repeatable)")
    add_reference_argument(parser, training=True)
    add_fill_gaps(parser)


def add_selection_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--max-sensors", type=int, default=TrainOptions.max_sensors,
                        metavar="N",
                        help="most sensors per axis (default %(default)s, the firmware budget)")
    parser.add_argument("--groups", type=int, default=TrainOptions.groups, metavar="C",
                        help="c-means groups (default %(default)s, capped by the sensor count)")
    parser.add_argument("--selection", choices=METHODS, default=TrainOptions.selection,
                        help="'validated' (default): representatives and EC subset by "
                        "out-of-fold error; 'paper': paper 000 exactly (training error); "
                        "'validated-refined': plus swaps within a group; 'validated-ec': "
                        "out-of-fold error, EC count (docs/selection.md)")
    parser.add_argument("--max-delay-h", type=float, default=None, metavar="H",
                        help="limit of the delay search (default a quarter of the shortest run)")
    parser.add_argument("--blocks", type=int, default=TrainOptions.n_blocks, metavar="N",
                        help="time blocks for validation when there is one run (default "
                        "%(default)s)")
    parser.add_argument("--seed", type=seed_arg, default=TrainOptions.seed,
                        help="c-means seed (default %(default)s)")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN.csv", help="training runs")
    add_data_arguments(parser, tilts=True)
    add_selection_arguments(parser)
    parser.add_argument("--channel", action="append", type=parse_channel, default=[],
                        metavar="SENSOR=INDEX", help="wire a sensor to a box channel "
                        "(default 0..k-1 in column order)")
    parser.add_argument("--max-channels", type=int, default=TrainOptions.max_channels,
                        metavar="N",
                        help="thermocouple channels the box has, shared by all axes (default "
                        "%(default)s); when the axes' choices exceed it, every axis is "
                        "re-selected from the sensors most axes chose")
    parser.add_argument("--tc-type", choices=TC_TYPES, default=TrainOptions.tc_type,
                        help="thermocouple type of every channel (default %(default)s)")
    parser.add_argument("--out", default="build", metavar="DIR",
                        help="output directory (default %(default)s)")
    parser.add_argument("--no-codegen", action="store_true",
                        help="only write model.json (skip DIR/model.h)")
    parser.add_argument("--no-effects", action="store_true",
                        help="the baseline alone: do not search the residual for effects "
                        "(lag, rate, ambient, speed, drift, nonlinear; docs/effects.md)")
    parser.add_argument("--ambient", metavar="COL", default=None,
                        help="ambient temperature column for the ambient effect (one of the "
                        "--sensors; default: a sensor named like *amb*, if any)")
    parser.add_argument("--fit", choices=FITS, default=TrainOptions.fit,
                        help="ridge (default): the selected terms and effects plus the speed "
                             "and lags of every sensor the box reads, shrunk (every um/K "
                             "alike); ols: least squares on "
                             "the selected terms and effects (paper 000's eq. 4); auto: the "
                             "family with the lowest nested error (docs/training.md)")
    parser.add_argument("--prefilter-s", type=float, default=TrainOptions.prefilter_s,
                        metavar="S",
                        help="the ridge is fitted to its rows low-passed by this time constant "
                             "(the probes' and thermocouples' noise out of the fit; the box "
                             "runs the same coefficients on raw readings); 0: the raw rows "
                             "(default %(default)g; docs/training.md)")
    parser.add_argument("--no-fill-channels", action="store_true",
                        help="the ridge reads only the selected sensors (default: also the "
                             "best of the others, by an L1 ranking, on the box's free channels)")
    parser.add_argument("--no-nested", action="store_true",
                        help="skip nested validation (the pipeline refitted per fold: the "
                             "promised error); 3-4x faster; auto then means ols")
    parser.add_argument("--jobs", type=int, default=None, metavar="N",
                        help="processes that train the nested folds of a long run at once "
                             "(default 1: this process only; forked workers pay only on an "
                             "idle machine and each adds its memory); the model is the same "
                             "whatever N")
    parser.add_argument("--service", nargs="+", action="extend", default=[], metavar="LOG.csv",
                        help="service logs (host fleet export, or runs with the box's channels "
                        "and sparse probe_<axis> columns): the trained terms' coefficients are "
                        "refitted to their probe readings if held-out logs gain 5 %%; opt-in, "
                        "neutral on the simulator so far (docs/service.md)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def _fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


# measured in docs/lab/accuracy.md ("Against the floor": sim_dev's 78 cases against its
# oracle, 2.5-3.9x trained on one day, 1.37x on two)
ONE_RUN_HINT = ("one training run: its blocks judge the model; a second day with another "
                "spindle program is the largest gain measured (on an independent simulator, "
                "unseen days at 2.5-3.9x the physical floor with one day, 1.4x with two; "
                "docs/lab/accuracy.md)")


def print_table(doc: dict, model: dict) -> None:
    print(f"model: {doc['model']}  (selection: {model['training']['selection']}, validation: "
          f"{model['training']['validation']})")
    print(f"{'axis':<10} {'sensors':<34} {'train um':>9} {'valid um':>9} {'raw um':>9} "
          f"{'R2':>7} {'cond':>7}")
    for name, a in doc["axes"].items():
        print(f"{name:<10} {','.join(a['sensors']):<34} {_fmt(a['train_rmse_um']):>9} "
              f"{_fmt(a['validation_rmse_um']):>9} {_fmt(a['raw_rms_um']):>9} "
              f"{_fmt(a['r2'], 4):>7} {_fmt(a['condition_number']):>7}")
    if any(unit_of(name) != "um" for name in doc["axes"]):
        print("(errors of a tilt axis, *_urad, are in urad)")
    own = sorted({a["validation"] for a in doc["axes"].values() if a.get("validation")}
                 - {model["training"]["validation"]})
    if own:  # the ridge chooses its penalty on folds of its own (two runs: each run's blocks)
        print(f"(valid um of the box's model: {'; '.join(own)})")
    print_effects(doc)
    for name, a in doc["axes"].items():
        folds = a.get("promised_fold_rmse_um") or []
        if a.get("promised_rmse_um") is not None and folds:
            u = unit_of(name)
            print(f"{name}: promised: {a.get('promise') or _fmt(a['promised_rmse_um'])} ("
                  f"{promise_rule(len(folds))}; folds {_fmt(min(folds))}-{_fmt(max(folds))} "
                  f"{u}), fit {a.get('fit')}"
                  + (f" (bending: an even warming penalised {_fmt(a['even_warming_penalty'])}x)"
                     if a.get("even_warming_penalty") else "")
                  + (f", free channels read: {','.join(a['free_channels_read'])}"
                     if a.get("free_channels_read") else ""))
    if len(model["training"]["runs"]) == 1:
        print(ONE_RUN_HINT)
    filters = [Term.from_json(t) for a in model["axes"].values() for t in a["terms"]]
    if any(t.kind in FILTER_KINDS for t in filters):
        print(f"filter states: {filter_states(filters)} of {BOX_STATES} (the lags and rates of "
              f"one sensor and time constant share one on every axis)")
    if "header" in doc:
        print(f"header: {doc['header']}")


def print_effects(doc: dict) -> None:
    """Each axis's validation RMSE before/after effects, what was added and why; an effect the
    channel budget dropped afterwards is listed as dropped (the box does not run it)."""
    for name, a in doc["axes"].items():
        u = unit_of(name)
        before = a.get("baseline_validation_rmse_um")
        searched, after = a.get("effects_validation_rmse_um"), a.get("validation_rmse_um")
        effects = a.get("effects") or []
        kept = [e for e in effects if not dropped_reason(e)]
        if kept:
            verb = "lowered" if searched is not None and before is not None \
                and searched <= before else "changed"
            print(f"{name}: the effect search {verb} the validation RMSE {_fmt(before)} -> "
                  f"{_fmt(searched)} {u} (least squares on the selected terms); the box's "
                  f"model ({a.get('fit') or 'ols'}) validates at {_fmt(after)} {u} on its own "
                  "folds, which do not see the next day: the promise below does")
        elif effects and a.get("effects_rejected"):
            print(f"{name}: the box's model runs without the effects: "
                  f"{a['effects_rejected']}")
        elif effects:
            print(f"{name}: no effect survived the channel budget (validation RMSE "
                  f"{_fmt(after)} {u})")
        box = a.get("box_nested_rmse_um")
        if box and box["without_effects"]:
            change = 100.0 * (box["with_effects"] / box["without_effects"] - 1.0)
            print(f"  the box's model on the nested folds (the pipeline, effects search "
                  f"included, refitted without each fold): {_fmt(box['without_effects'])} {u} "
                  f"without the effects, {_fmt(box['with_effects'])} {u} with them "
                  f"({change:+.0f} %); a weak guide to the next day (docs/training.md): "
                  "judge the effects on a run the model never saw "
                  "(host report --runs)")
        for e in effects:
            ev = e.get("evidence") or {}
            why = dropped_reason(e)
            mark = "x" if why else "+"
            print(f"  {mark} {e['kind']:<9} {e['feature']}: {_fmt(e.get('rmse_before_um'))} -> "
                  f"{_fmt(e.get('rmse_after_um'))} {u}, {ev.get('folds_improved', '?')} folds "
                  f"better, residual correlation {_fmt(ev.get('residual_corr'), 2)}"
                  + (f"  DROPPED: {why}, not in the box's model" if why else "")
                  + (f"  ({ridge_lags_note(e)})" if ridge_lags_note(e) else ""))
        after = a.get("channel_budget_after_effects")
        if after:
            print(f"  {name}: the box's {after['max_channels']} channels, shared by all axes, "
                  f"then dropped {', '.join(after['dropped_sensors'])} (terms "
                  f"{', '.join(after['dropped_terms'])}); the box runs "
                  f"{', '.join(a['sensors'])} and the errors above are its own")
        if a.get("unexplained"):
            note = " (said of the model before the channel budget)" if after else ""
            print(f"  {name} unexplained{note}: {a['unexplained']['message']}")


TARGET_SUFFIXES = ("_um", "_urad")  # displacement in um, tilt in urad (contract.tilt)


def check_targets(targets: list[str], sensors: str | list[str]) -> None:
    """A target is a displacement (``*_um``) or a tilt (``*_urad``), never a temperature
    column: ``--target T01`` trained a temperature as micrometres."""
    for name in targets:
        pattern = sensors if isinstance(sensors, str) else None
        if (pattern is not None and fnmatch.fnmatchcase(name, pattern)) or (
                not isinstance(sensors, str) and name in sensors):
            raise InputError(f"--target {name}: that is a temperature column (it matches "
                             f"--sensors {sensors!r}); a target is a measured displacement "
                             "(a column named *_um) or a tilt (*_urad)")
        if not name.endswith(TARGET_SUFFIXES):
            raise InputError(f"--target {name}: a target's name says its unit: a displacement "
                             "in um ends in _um, a tilt in urad in _urad (the box, the monitor "
                             "and LinuxCNC read the unit from it); rename the column")


def check_distinct_runs(paths: list[str]) -> None:
    """The same run given twice would count as two runs in validation (a run 'unseen' by
    the fit that it was trained on)."""
    seen: dict[object, str] = {}
    for path in paths:
        p = Path(path)
        try:
            key: object = p.resolve(strict=True)
            digest = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError:
            continue  # load_runs names a missing or unreadable file
        for k in (key, digest):
            if k in seen:
                same = "is the same file as" if k == key else "has the same content as"
                raise InputError(f"{path} {same} {seen[k]}: each training run must be a "
                                 "different run (validation holds runs out of the fit)")
            seen[k] = path


def run(args: argparse.Namespace) -> int:
    targets = [*args.target, *(t.name for t in args.tilt if t.name not in args.target)]
    if not targets:
        raise InputError("give at least one --target (or --tilt)")
    check_targets(list(args.target), args.sensors)
    check_distinct_runs(list(args.runs))
    runs = load_runs(args.runs, targets, args.sensors, args.aux, args.fill_gaps,
                     min_samples=4, fmt=csv_format(args), tilts=args.tilt)
    # column-major, the layout train_model's own copy of the sensors would have: it uses
    # these arrays instead (one copy of a day's temperatures less in memory)
    runs = [replace(r, temperatures=np.asfortranarray(r.temperatures)) for r in runs]
    model = train_model(runs, targets, sensors=args.sensors, aux=args.aux,
                        max_sensors=args.max_sensors, groups=args.groups,
                        effects=not args.no_effects, ambient=args.ambient,
                        channels=dict(args.channel), selection=args.selection,
                        max_delay_s=None if args.max_delay_h is None else args.max_delay_h * 3600,
                        n_blocks=args.blocks, seed=args.seed, fill_gaps=args.fill_gaps,
                        tc_type=args.tc_type, max_channels=args.max_channels,
                        reference=args.reference, fit=args.fit, nested=not args.no_nested,
                        fill_channels=not args.no_fill_channels, tilts=args.tilt,
                        bending=args.bending, prefilter_s=args.prefilter_s, jobs=args.jobs,
                        quiet=args.json)
    if args.service:
        logs = load_service_logs(args.service, model, args.fill_gaps, csv_format(args))
        model = refit_on_probes(model, runs, logs)
    out = Path(args.out)
    model_path = out / "model.json"
    header = None
    if not args.no_codegen:  # train owns its model.json: the fixed_point block goes in with it
        from thermal_comp import codegen

        try:
            gen = codegen.generate(model)
        except ValueError as exc:
            write_model(model, model_path)
            raise InputError(f"{model_path} written, but codegen refused it: {exc}") from None
        model["fixed_point"] = gen.fixed_point
        header = out / "model.h"
    write_model(model, model_path)
    doc = summary(model, str(model_path))
    if header is not None:
        write_text_atomic(header, gen.text)
        doc["header"] = str(header)
    if args.json:
        print(json.dumps(jsonable(doc), indent=2, allow_nan=False))
    else:
        print_table(doc, model)
    return 0
