"""`host train`: the runs' path through training, one stage after the other.

``train_model`` is the library entry point (the CLI, the demo, `host compare` and the tests use
it). Its options are declared and checked once (host.train.options); the runs become one
view (host.train.training_data); per target axis the selection within the box's channel
budget, the fit and the effects (host.train.searched), then the model for the next day
(host.train.next_day_fit: nested validation, the ridge); host.train.record turns the results
into the model.json dict (docs/model-json.md), and the box's step limits and in-service
parameters are added to it.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import fields
from functools import cache, wraps
from pathlib import Path

from threadpoolctl import threadpool_limits

from thermal_comp.host.fitting import Reference
from thermal_comp.host.fitting.step_limits import add_step_limits
from thermal_comp.host.io import Run
from thermal_comp.host.service import add_service
from thermal_comp.host.train.channel_budget import channels_of
from thermal_comp.host.train.free_channels import fill_rankings
from thermal_comp.host.train.next_day_fit import NextDayFit, NextDayJob, for_the_next_day
from thermal_comp.host.train.options import TrainOptions
from thermal_comp.host.train.record import model_json
from thermal_comp.host.train.searched import (
    SearchedAxis,
    axes_with_effects,
    budget_after_effects,
    free_channel_fill,
    selected_within_budget,
)
from thermal_comp.host.train.training_data import TrainingData, TrainingError, as_runs

# BLAS on one thread while training: its matrices have tens of columns, and OpenBLAS's threads
# spin between calls. `host train` on 64 sensors x 86,400 rows used 10.9-14.6 s of CPU with two
# threads and 7.3-9.1 s with one on the 2-core target (the same model; docs/selection.md
# section 7).
# The limit is the process's while train_model runs (threadpoolctl; scikit-learn's KMeans
# limits its BLAS the same way) and is restored when it returns. It covers the BLAS libraries
# loaded when it is set: numpy's, and scipy's own (scikit-learn's lasso calls it).
BLAS_THREADS = 1


def _one_blas_thread(train: Callable[..., dict]) -> Callable[..., dict]:
    """``train`` with BLAS on ``BLAS_THREADS`` threads while it runs (see BLAS_THREADS)."""
    @wraps(train)
    def limited(*args, **kwargs) -> dict:
        import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, loaded so the limit covers it)

        with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            return train(*args, **kwargs)
    return limited


def _train_signature(train: Callable[..., dict]) -> Callable[..., dict]:
    """``train`` with the signature ``train_model(runs, targets, *, <TrainOptions' fields>)``:
    the options are declared once (host.train.options), and callers that look at the
    keywords (bench.bench_accuracy.train_kwargs) still see each."""
    keywords = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default,
                                  annotation=f.type) for f in fields(TrainOptions)]
    train.__signature__ = inspect.signature(train).replace(  # type: ignore[attr-defined]
        parameters=[*list(inspect.signature(train).parameters.values())[:2], *keywords])
    return train


@_train_signature
def train_model(runs: Sequence[Run | str | Path], targets: Sequence[str], **options) -> dict:
    """Select, fit and validate a model for every target; returns the model.json dict.

    ``runs`` are CSV paths or loaded ``Run`` objects; ``options`` are host.train.options.
    TrainOptions' fields. ``selection`` is ``"validated"``
    (representatives and EC subset by out-of-fold error, default) or ``"paper"`` (paper 000
    exactly: by training error). ``channels`` maps sensor -> box channel (others get the
    free indices in data-column order). ``max_delay_s`` limits the delay search.
    ``fill_channels``: the ridge also reads the best-ranked other sensors on the box's free
    channels (host.train.free_channels.channel_fill). ``tilts``: targets that are tilt axes (µrad)
    computed from two gap probes of each run (contract/tilt.py); each must be a target.
    ``max_channels`` is the box's thermocouple budget shared by all axes
    (see fit_channel_budget). ``fill_first``: the free channels are filled before the effects
    are searched, which may then only use wired sensors (default: with several axes when the
    ridge reads them, i.e. ``fill_channels`` and a fit other than ``ols``; one axis's effects
    keep the first claim on them; see searched.free_channel_fill). ``bending``: targets that a
    temperature difference across the structure moves rather than an even warming (a
    column's bending: Y of a vertical machining center); their ridge penalises the response
    to an even warming (host.train.ridge_family.EVEN_WARMING_PENALTY). ``prefilter_s``: the time
    constant (s) of the low-pass the ridge's rows are fitted through (host.fitting.prefilter;
    0: the raw rows). ``jobs``: at most this many processes train the nested folds (default:
    host.parallel.default_workers; 1: this process); the model does not depend on it.
    """
    return _train(runs, list(targets), TrainOptions.of(**options))


@_one_blas_thread
def _train(runs: Sequence[Run | str | Path], targets: list[str], o: TrainOptions) -> dict:
    """train_model on its options: the stages in order, then the record, written once."""
    data, axes, fits = _stages(runs, targets, o)
    model = model_json(data, targets, o, axes, fits)
    # how fast each input and output may change on the box (IMPLAUSIBLE, step limit)
    add_step_limits(model, data.runs)
    # the in-service estimator's parameters from the out-of-fold residual (issue 42)
    add_service(model, data.runs, data.n_blocks, data.ref)
    return model


@_one_blas_thread
def _fold_axis(runs: list[Run], target: str, o: TrainOptions) -> SearchedAxis:
    """A nested fold's training of one axis (``o``: TrainOptions.for_fold): the stages alone,
    typed; a fold reads the axis's terms and effects, never a record."""
    return _stages(runs, [target], o)[1][target]


def _stages(runs: Sequence[Run | str | Path], targets: list[str], o: TrainOptions
            ) -> tuple[TrainingData, dict[str, SearchedAxis], dict[str, NextDayFit]]:
    """The runs' path through training: the options checked, the runs' one view, the
    selection within the channel budget, the fit and the effects, the model for the next day;
    each axis and its choice typed."""
    o.check(targets)
    sensors = o.sensors if isinstance(o.sensors, str) else list(o.sensors)
    data = TrainingData.of(as_runs(runs, targets, sensors, list(o.aux), o.fill_gaps, o.tilts),
                           targets, o.n_blocks, Reference.of_kind(o.reference))
    choose = dict(groups=o.groups, max_sensors=o.max_sensors, selection=o.selection,
                  max_delay_s=o.max_delay_s, seed=o.seed)
    selected = selected_within_budget(data, targets, o.max_channels, choose, o.quiet)
    data.done_selecting()
    fill_first = o.fill_first
    if fill_first is None:  # the harm it prevents is between axes (free_channel_fill)
        fill_first = o.fill_channels and o.fit != "ols" and len(targets) > 1
    # the axes' L1 rankings for the free channels: once, for the fill before the effects and
    # again after them (they do not depend on what is wired)
    rankings = cache(lambda: fill_rankings(data.runs, targets, data.pool,
                                           period_s=data.period_s, n_blocks=data.n_blocks,
                                           reference=data.ref))
    fill = free_channel_fill(data, selected, o.max_channels, rankings) if fill_first else []
    axes = axes_with_effects(data, selected, effects=o.effects, ambient=o.ambient,
                             max_sensors=o.max_sensors, max_channels=o.max_channels,
                             fill=fill, quiet=o.quiet)
    axes = budget_after_effects(data, axes, o.max_channels)
    fits: dict[str, NextDayFit] = {}
    if o.nested or o.fit == "ridge":
        job = NextDayJob(data, _fold_axis, o.for_fold(data.names, fill_first), o.fit,
                         o.fill_channels, o.max_channels, o.bending, o.prefilter_s, o.jobs,
                         o.quiet, rankings)
        axes, fits = for_the_next_day(job, axes, nested=o.nested)
    _check_budget(axes, o.max_channels)
    return data, axes, fits


def _check_budget(axes: dict[str, SearchedAxis], max_channels: int) -> None:
    """The box's channel budget over all axes: a guarantee of the stages, checked, never
    assumed."""
    used = channels_of({t: a.fit.terms for t, a in axes.items()})
    if len(used) > max_channels:
        raise TrainingError(f"model needs {len(used)} thermocouple channels "
                            f"({', '.join(sorted(used))}), the box has {max_channels}")
