"""The report's figures, one idea each, drawn with matplotlib's Agg canvas (no display needed).

Every function takes plain arrays and names (no model or run objects), returns a
``matplotlib.figure.Figure`` and leaves saving to the caller (``save_png``, which also says
which legends and labels would be cut off at the PNG's edge: ``clipped_artists``; both live in
host.analysis.png and are named here too); ``Figure`` is used directly rather than ``pyplot``
so no global state or GUI backend is involved.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.transforms import offset_copy  # noqa: E402

from thermal_comp.contract.tilt import unit_of, unit_text  # noqa: E402
from thermal_comp.host.analysis.png import PNG_DPI as PNG_DPI  # noqa: E402
from thermal_comp.host.analysis.png import clipped_artists as clipped_artists  # noqa: E402
from thermal_comp.host.analysis.png import save_png as save_png  # noqa: E402

WIDE = (9.0, 5.0)
SQUARE = (7.0, 6.0)
OURS_COLOUR = "tab:blue"
PEER_COLOURS = ("tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
HEATING_COLOUR = "tab:red"
COOLING_COLOUR = "tab:blue"
LEGEND_WRAP = 60  # characters per legend line below a WIDE figure (two columns fit 9 inches)


def wrap_label(text: str, width: int = LEGEND_WRAP) -> str:
    """A legend entry broken into lines of at most ``width`` characters."""
    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=False)) or text


def time_axis(time_s: np.ndarray) -> tuple[np.ndarray, str]:
    """Time in the unit a reader thinks in: minutes for short runs, hours for long ones."""
    span = float(time_s[-1] - time_s[0]) if len(time_s) else 0.0
    if span > 3 * 3600:
        return time_s / 3600.0, "time (h)"
    if span > 180:
        return time_s / 60.0, "time (min)"
    return time_s, "time (s)"


def delay_axis(delays_s: np.ndarray) -> tuple[np.ndarray, str]:
    span = float(np.max(np.abs(delays_s))) if len(delays_s) else 0.0
    if span > 3 * 3600:
        return delays_s / 3600.0, "time delay τ (h)"
    if span > 180:
        return delays_s / 60.0, "time delay τ (min)"
    return delays_s, "time delay τ (s)"


def axis_unit(axis: str) -> tuple[str, str]:
    """The unit text and the quantity of an axis: µm displacement, or µrad tilt."""
    return unit_text(axis), "tilt" if unit_of(axis) == "urad" else "displacement"


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def _spread_labels(points: Sequence[tuple[float, float]], min_gap: float) -> list[float]:
    """Vertical label positions (in axis fraction units) so that no two labels overprint:
    labels are sorted by height and pushed apart by at least ``min_gap``."""
    order = sorted(range(len(points)), key=lambda i: points[i][1])
    ys = [0.0] * len(points)
    last = -np.inf
    for i in order:
        y = max(points[i][1], last + min_gap)
        ys[i] = y
        last = y
    return ys


def selection_plane(axis: str, sensors: Sequence[str], delays_s: Sequence[float],
                    correlations: Sequence[float], labels: Sequence[int],
                    chosen: Sequence[str], dropped: Sequence[str] = (),
                    delay_limit_s: float | None = None) -> Figure:
    """Paper 000 Fig. 7: sensors in the (delay, correlation) plane by cluster, with each
    cluster's centre (the mean of its members: c-means runs on standardised axes, an affine
    map, so the centre in these units is the members' mean); ``chosen`` (read by the box) are
    circled and named, ``dropped`` (chosen by the selection, then taken away by the box's
    channel budget) get a dashed grey circle; sensors whose delay sits at the limit of the
    search (``delay_limit_s``) are marked with a triangle: their true delay may be longer.

    Label -1 marks sensors the channel budget kept out of the selection (grey crosses).
    When every group has one member (c-means was capped at the number of candidates), the
    candidates are drawn in one colour as such, without centres: there are no groups to show."""
    fig = Figure(figsize=(10.0, 6.0), layout="constrained")
    ax = fig.add_subplot()
    raw_delays = np.asarray(delays_s, dtype=float)
    delays, xlabel = delay_axis(raw_delays)
    corr = np.asarray(correlations, dtype=float)
    alone = _sensor_groups(ax, delays, corr, np.asarray(labels, dtype=int))
    if delay_limit_s is not None and delay_limit_s > 0:
        _search_limit(ax, raw_delays, delays, corr, delay_limit_s, xlabel)
    chosen_set, dropped_set = set(chosen), set(dropped)
    _circle_and_name(fig, ax, sensors, delays, corr, chosen_set, dropped_set)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("correlation coefficient r with displacement (–)")
    ax.set_title(f"{axis}: sensors " + ("by delay and correlation (each its own group)"
                                        if alone else "grouped by delay and correlation")
                 + f",\n{len(chosen_set)} of {len(sensors)} read by the box")
    ax.grid(True, alpha=0.3)
    fig.legend(fontsize=8, loc="outside right upper")
    return fig


def _sensor_groups(ax, delays: np.ndarray, corr: np.ndarray, labels_arr: np.ndarray) -> bool:
    """Each group of sensors in its colour with its centre, those without a box channel as
    grey crosses; True when every group has one member (then drawn as candidates, no
    centres: there are no groups to show)."""
    groups = sorted(set(labels_arr.tolist()))
    offered = [g for g in groups if g >= 0]
    alone = len(offered) > 1 and all(int((labels_arr == g).sum()) == 1 for g in offered)
    cmap = matplotlib.colormaps["tab10" if len(groups) <= 10 else "tab20"]
    if alone:
        mask = labels_arr >= 0
        ax.scatter(delays[mask], corr[mask], s=40, color=OURS_COLOUR, alpha=0.85,
                   label=f"candidate, a group of its own ({int(mask.sum())})")
    for k, group in enumerate(groups):
        mask = labels_arr == group
        if group < 0:  # not offered to the selection (no box channel left for it)
            ax.scatter(delays[mask], corr[mask], s=40, color="0.75", marker="x",
                       label=f"no channel on the box ({int(mask.sum())})")
            continue
        if alone:
            continue
        colour = cmap(k % cmap.N)
        ax.scatter(delays[mask], corr[mask], s=40, color=colour, alpha=0.85,
                   label=f"group {group} ({int(mask.sum())})")
        cx, cy = float(np.mean(delays[mask])), float(np.mean(corr[mask]))
        ax.scatter([cx], [cy], s=90, marker="D", facecolors="none", edgecolors=colour,
                   linewidths=1.5, zorder=1)
    if not alone:
        ax.scatter([], [], s=90, marker="D", facecolors="none", edgecolors="0.4",
                   linewidths=1.5, label="group centre (mean of members)")
    return alone


def _search_limit(ax, raw_delays: np.ndarray, delays: np.ndarray, corr: np.ndarray,
                  delay_limit_s: float, xlabel: str) -> None:
    """The delay search's limits as dotted lines, and a triangle on each sensor whose delay
    sits at one: its true delay may be longer."""
    scale = 1 / 3600.0 if "(h)" in xlabel else 1 / 60.0 if "(min)" in xlabel else 1.0
    edge = np.abs(raw_delays) >= delay_limit_s - 1e-6
    if edge.any():
        ax.scatter(delays[edge], corr[edge], s=420, marker="^", facecolors="none",
                   edgecolors="tab:red", linewidths=1.4, zorder=4,
                   label=f"delay at the search limit (±{delay_limit_s * scale:.3g} "
                         f"{xlabel.rsplit('(', 1)[-1].rstrip(')')})")
    for x in (-delay_limit_s * scale, delay_limit_s * scale):
        ax.axvline(x, color="tab:red", ls=":", lw=0.8)


def _circle_and_name(fig: Figure, ax, sensors: Sequence[str], delays: np.ndarray,
                     corr: np.ndarray, chosen_set: set[str], dropped_set: set[str]) -> None:
    """The sensors the box reads circled in black, those dropped by its channel budget in
    dashed grey, each named to its right (pushed apart so no two names overprint)."""
    named = [(n, float(x), float(y)) for n, x, y in zip(sensors, delays, corr, strict=True)
             if n in chosen_set or n in dropped_set]
    for name, x, y in named:
        if name in chosen_set:
            ax.scatter([x], [y], s=220, facecolors="none", edgecolors="black", linewidths=2)
        else:
            ax.scatter([x], [y], s=220, facecolors="none", edgecolors="0.5", linewidths=1.5,
                       linestyle="--")
    ylim = ax.get_ylim()
    span = (ylim[1] - ylim[0]) or 1.0
    label_y = _spread_labels([(x, y) for _, x, y in named], 0.045 * span)
    shifted = offset_copy(ax.transData, fig=fig, x=10, y=0, units="points")
    for (name, x, y), ly in zip(named, label_y, strict=True):
        keep = name in chosen_set
        ax.annotate(name if keep else f"{name} (dropped)", (x, y), xytext=(x, ly),
                    textcoords=shifted, fontsize=10 if keep else 9,
                    fontweight="bold" if keep else "normal", color="black" if keep else "0.4",
                    ha="left", va="center",
                    arrowprops=None if abs(ly - y) < 1e-9 else dict(arrowstyle="-", lw=0.5,
                                                                    color="0.5"))
    ax.scatter([], [], s=220, facecolors="none", edgecolors="black", linewidths=2,
               label="read by the box")
    if dropped_set:
        ax.scatter([], [], s=220, facecolors="none", edgecolors="0.5", linewidths=1.5,
                   linestyle="--", label="chosen, then dropped (not read by the box)")


def ec_curve(axis: str, ec: Sequence[float], chosen_count: int,
             subsets: Sequence[Sequence[str]] | None = None,
             errors: Sequence[float] | None = None, rule: str = "ec",
             max_sensors: int | None = None,
             fold_errors: Sequence[Sequence[float]] | None = None) -> Figure:
    """Paper 000 Fig. 8: EC_i over model size; with ``errors`` also S_i itself (right axis).

    ``rule`` says what fixed the count: "ec" (paper 000: smallest EC_i), "min" (validated:
    smallest out-of-fold S_i) or "cap" (the smallest S_i lay beyond ``max_sensors``, so the cap
    decided); the chosen size is circled on the curve that fixed it, the cap drawn as a line.
    ``fold_errors`` (each size's held-out RMSE per fold) draws S_i's bar from the best to the
    worst fold.
    """
    unit, what = axis_unit(axis)
    fig = Figure(figsize=WIDE, layout="constrained")
    ax = fig.add_subplot()
    sizes = np.arange(1, len(ec) + 1)
    lines = ax.plot(sizes, ec, "o-", color=OURS_COLOUR, label="EC$_i$ = (S$_i$/S$_1$)·(i/c)")
    ax.set_ylabel("evaluation criterion EC$_i$ (–)")
    marked_ax, marked = ax, list(ec)
    if errors is not None and len(errors) == len(ec):
        ax2 = ax.twinx()
        label = f"S$_i$, error of the best i-sensor model ({unit})"
        if fold_errors is not None and len(fold_errors) == len(errors):
            pairs = list(zip(errors, fold_errors, strict=True))
            lo = [max(e - min(f), 0.0) if len(f) else 0.0 for e, f in pairs]
            hi = [max(max(f) - e, 0.0) if len(f) else 0.0 for e, f in pairs]
            ax2.errorbar(sizes, errors, yerr=[lo, hi], fmt="none", ecolor=PEER_COLOURS[0],
                         alpha=0.6, capsize=3)
            label += ", bar: best to worst fold"
        lines += ax2.plot(sizes, errors, "s--", color=PEER_COLOURS[0], label=label)
        ax2.set_ylabel(f"S$_i$ ({unit})")
        if rule in ("min", "cap"):
            marked_ax, marked = ax2, list(errors)
    if max_sensors is not None and max_sensors < len(ec):
        lines.append(ax.axvline(max_sensors + 0.5, color="0.3", ls=":", lw=1.2,
                                label=f"--max-sensors {max_sensors}"))
    if 1 <= chosen_count <= len(ec):
        y = marked[chosen_count - 1]
        lines.append(marked_ax.scatter([chosen_count], [y], s=250, facecolors="none",
                                       edgecolors="tab:red", linewidths=2.5, zorder=3,
                                       label=f"chosen: {chosen_count} sensors"))
        if subsets and len(subsets) >= chosen_count:
            marked_ax.annotate(", ".join(subsets[chosen_count - 1]), (chosen_count, y),
                               xytext=(0, 18), textcoords="offset points", ha="center",
                               fontsize=10, bbox=dict(boxstyle="round", fc="white", ec="0.8",
                                                      alpha=0.9))
    ax.set_xticks(sizes)
    ax.set_xlabel("number of sensors i in the model")
    ax.set_title(f"{axis}: " + {
        "ec": "model size chosen where EC is smallest (paper 000)",
        "min": "model size chosen where the out-of-fold error S is smallest",
        "cap": f"model size capped by --max-sensors {max_sensors} "
               "(S is smallest beyond the cap)"}[rule])
    ax.grid(True, alpha=0.3)
    ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper center")
    return fig


def run_fit(run: str, axis: str, time_s: np.ndarray, measured: np.ndarray,
            predictions: Mapping[str, np.ndarray],
            promise: tuple[float, Sequence[float]] | None = None) -> Figure:
    """Measured displacement, each model's prediction (top) and its residual (bottom).

    ``promise`` (the error ``host train`` promised for an unseen day, its lowest nested fold,
    and the per-fold values) is drawn on the residual as a band of ± that RMS, the worst fold
    as dotted lines."""
    unit, what = axis_unit(axis)
    fig = Figure(figsize=(9.0, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    t, tlabel = time_axis(np.asarray(time_s, dtype=float))
    top.plot(t, measured, color="black", lw=2.2, label=f"measured (RMS {rms(measured):.2f} {unit})")
    for k, (name, pred) in enumerate(predictions.items()):
        colour = OURS_COLOUR if k == 0 else PEER_COLOURS[(k - 1) % len(PEER_COLOURS)]
        style = "-" if k == 0 else "--"
        top.plot(t, pred, style, color=colour, lw=1.5, label=f"{name}")
        residual = measured - pred
        bottom.plot(t, residual, style, color=colour, lw=1.2,
                    label=f"{name}: RMS {rms(residual):.2f} {unit}")
    bottom.axhline(0.0, color="black", lw=0.8)
    if promise is not None and math.isfinite(promise[0]):
        band, folds = promise
        label = f"promised for an unseen day: ±{band:.2f} {unit} RMS"
        bottom.axhspan(-band, band, color=OURS_COLOUR, alpha=0.12, lw=0)
        if len(folds):
            worst = max(folds)
            label += f" (folds {min(folds):.2f}–{worst:.2f} {unit}, worst dotted)"
            for y in (-worst, worst):
                bottom.axhline(y, color=OURS_COLOUR, lw=0.8, ls=":")
        bottom.plot([], [], color=OURS_COLOUR, alpha=0.3, lw=6, label=label)
    top.set_ylabel(f"{what} ({unit})")
    top.set_title(f"{run}, {axis}: prediction against measurement")
    top.legend(fontsize=8, loc="best")
    top.grid(True, alpha=0.3)
    bottom.set_ylabel(f"residual = measured − predicted ({unit})")
    bottom.set_xlabel(tlabel)
    bottom.legend(fontsize=8, loc="best")
    bottom.grid(True, alpha=0.3)
    return fig


def service_day(run: str, axis: str, time_s: np.ndarray, measured: np.ndarray,
                static: np.ndarray, updated: np.ndarray, probe_only: np.ndarray,
                index: np.ndarray, value: np.ndarray, accepted: np.ndarray) -> Figure:
    """A day in service (issue 42): the measured displacement with the model alone, the
    model updated by the probe and the last probe reading held (top), what each leaves
    (bottom, RMS in the legend); the readings are marked where and when they were taken,
    filled when the gate accepted them, a cross when it refused them."""
    unit, what = axis_unit(axis)
    fig = Figure(figsize=(9.0, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    t, tlabel = time_axis(np.asarray(time_s, dtype=float))
    lines = (("static (the model alone)", static, "tab:gray", "--"),
             ("updated (the model + the probe's estimate)", updated, OURS_COLOUR, "-"),
             ("probe-only (last reading held)", probe_only, "tab:orange", ":"))
    top.plot(t, measured, color="black", lw=2.2, label="measured")
    for label, y, colour, style in lines:
        top.plot(t, y, style, color=colour, lw=1.5, label=label)
        residual = measured - y
        bottom.plot(t, residual, style, color=colour, lw=1.2,
                    label=wrap_label(f"{label}: RMS {rms(residual):.2f} {unit}"))
    idx = np.asarray(index, dtype=int)
    ok = np.asarray(accepted, dtype=bool)
    value = np.asarray(value, dtype=float)
    if np.any(ok):
        top.plot(t[idx[ok]], value[ok], "o", color="tab:red", ms=5,
                 label=f"probe reading, accepted ({int(ok.sum())})")
    if np.any(~ok):
        top.plot(t[idx[~ok]], value[~ok], "x", color="tab:red", ms=7, mew=2,
                 label=f"probe reading, refused by the gate ({int((~ok).sum())})")
    for k in idx:
        bottom.axvline(t[k], color="tab:red", lw=0.6, alpha=0.5)
    bottom.plot([], [], color="tab:red", lw=0.6, alpha=0.5, label="probe times")
    bottom.axhline(0.0, color="black", lw=0.8)
    top.set_ylabel(f"{what} ({unit})")
    top.set_title(f"{run}, {axis}: a day in service")
    top.legend(fontsize=8, loc="best")
    top.grid(True, alpha=0.3)
    bottom.set_ylabel(f"measured − output ({unit})")
    bottom.set_xlabel(tlabel)
    bottom.legend(fontsize=8, loc="best")
    bottom.grid(True, alpha=0.3)
    return fig


def residual_steps(run: str, axis: str, time_s: np.ndarray,
                   stages: Sequence[tuple[str, np.ndarray]],
                   dropped: Sequence[bool] | None = None) -> Figure:
    """The residual after each model stage (baseline, then every effect added), RMS in legend.

    ``dropped`` marks stages that are not part of the final model (drawn dashed grey); the last
    stage is the final model and is drawn thickest."""
    unit, what = axis_unit(axis)
    labels = [wrap_label(f"{label}: RMS {rms(residual):.2f} {unit}")
              for label, residual in stages]
    half = -(-len(labels) // 2)  # two columns, filled column by column
    rows = max(sum(lb.count("\n") + 1 for lb in col) for col in (labels[:half], labels[half:]))
    fig = Figure(figsize=(WIDE[0], WIDE[1] + 0.17 * rows), layout="constrained")
    ax = fig.add_subplot()
    t, tlabel = time_axis(np.asarray(time_s, dtype=float))
    cmap = matplotlib.colormaps["viridis"]
    n = len(stages)
    gone = list(dropped) if dropped is not None else [False] * n
    kept = [k for k in range(n) if not gone[k]]
    for k, ((_, residual), label) in enumerate(zip(stages, labels, strict=True)):
        if gone[k]:
            ax.plot(t, residual, color="0.6", lw=1.0, ls="--", label=label)
            continue
        pos = kept.index(k)
        colour = cmap(0.85 * pos / max(1, len(kept) - 1))
        ax.plot(t, residual, color=colour, lw=2.0 if k == n - 1 else 1.6 if k == 0 else 1.0,
                label=label)
    ax.axhline(0.0, color="black", lw=0.8)
    ax.set_xlabel(tlabel)
    ax.set_ylabel(f"residual = measured − predicted ({unit})")
    ax.set_title(f"{run}, {axis}: residual before and after each added effect")
    ax.grid(True, alpha=0.3)
    fig.legend(fontsize=8, loc="outside lower center", ncol=2)
    return fig


def heating_mask(temperature: np.ndarray, period_s: float, window_s: float = 300.0) -> np.ndarray:
    """True where the temperature rises, judged on a moving average so noise does not flicker."""
    n = max(1, int(round(window_s / max(period_s, 1e-9))))
    kernel = np.ones(n) / n
    padded = np.pad(np.asarray(temperature, dtype=float), (n // 2, n - 1 - n // 2), mode="edge")
    smooth = np.convolve(padded, kernel, mode="valid")
    return np.gradient(smooth) >= 0.0


def _paths(ax, x: np.ndarray, y: np.ndarray, heating: np.ndarray) -> None:
    points = np.column_stack([x, y]).reshape(-1, 1, 2)
    segments = np.concatenate([points[:-1], points[1:]], axis=1)
    colours = np.where(heating[1:], HEATING_COLOUR, COOLING_COLOUR)
    ax.add_collection(LineCollection(segments, colors=colours, linewidths=1.4))
    ax.autoscale_view()


def training_window(run: str, time_s: np.ndarray, inputs: Mapping[str, np.ndarray],
                    ranges: Mapping[str, tuple[float, float]], margin: float) -> Figure:
    """Each input of the model over the run, scaled to its training range (0 = the coldest,
    1 = the hottest seen in training): the shaded band is where the model interpolates, the
    dashed lines where the box starts to flag EXTRAP; a curve beyond them is extrapolation."""
    fig = Figure(figsize=WIDE, layout="constrained")
    ax = fig.add_subplot()
    t, tlabel = time_axis(np.asarray(time_s, dtype=float))
    ax.axhspan(0.0, 1.0, color="tab:green", alpha=0.12, label="training range")
    for edge in (-margin, 1.0 + margin):
        ax.axhline(edge, color="tab:red", ls="--", lw=1.0)
    for name, x in inputs.items():
        lo, hi = ranges[name]
        span = hi - lo
        label = name if span > 0 else f"{name} (constant in training: offset in its unit)"
        ax.plot(t, (np.asarray(x, dtype=float) - lo) / (span if span > 0 else 1.0), lw=1.3,
                label=label)
    ax.set_xlabel(tlabel)
    ax.set_ylabel("position in the training range (–)")
    ax.set_title(f"{run}: inputs against their training range (dashed: EXTRAP)")
    ax.grid(True, alpha=0.3)
    fig.legend(fontsize=9, loc="outside right upper")  # beside the curves, never over them
    return fig


def fold_errors(axis: str, stages: Sequence[str], mean_um: Sequence[float],
                folds_um: Sequence[Sequence[float]], dropped: Sequence[bool]) -> Figure:
    """Validation RMSE of each model stage (baseline, then each effect) as the mean over the
    validation folds with error bars from the lowest to the highest fold, and each fold as a
    dot: how much of a gain is larger than the fold-to-fold spread."""
    unit, what = axis_unit(axis)
    fig = Figure(figsize=WIDE, layout="constrained")
    ax = fig.add_subplot()
    x = np.arange(len(stages))
    for k, (m, folds, gone) in enumerate(zip(mean_um, folds_um, dropped, strict=True)):
        f = np.asarray(folds, dtype=float)
        colour = "0.6" if gone else OURS_COLOUR
        lo, hi = (m - f.min(), f.max() - m) if f.size else (0.0, 0.0)
        ax.errorbar([k], [m], yerr=[[max(lo, 0.0)], [max(hi, 0.0)]], fmt="o", color=colour,
                    capsize=6, markersize=8, lw=1.5)
        ax.scatter(np.full(f.size, k + 0.12), f, s=14, color=colour, alpha=0.7)
    ax.set_xticks(x, [s if len(s) < 28 else s[:26] + "…" for s in stages], rotation=20,
                  ha="right")
    ax.set_ylabel(f"validation RMSE ({unit}): pooled, fold range, each fold")
    ax.set_title(f"{axis}: validation error of each stage across the folds")
    ax.set_ylim(bottom=0)
    ax.grid(True, axis="y", alpha=0.3)
    return fig


def hysteresis(run: str, axis: str, sensor: str, temperature: np.ndarray, measured: np.ndarray,
               residual: np.ndarray, period_s: float) -> Figure:
    """Displacement against the most important temperature: the heating/cooling loop
    (pseudo-hysteresis) before compensation, and what is left of it after."""
    unit, what = axis_unit(axis)
    fig = Figure(figsize=(10.0, 5.0), layout="constrained")
    left, right = fig.subplots(1, 2, sharey=True)
    heating = heating_mask(temperature, period_s)
    for ax, y, title in ((left, measured, "before compensation (measured)"),
                         (right, residual, "after compensation (residual)")):
        _paths(ax, temperature, y, heating)
        ax.set_title(f"{title}: span {np.ptp(y):.1f} {unit}")
        ax.set_xlabel(f"{sensor} temperature (°C)")
        ax.grid(True, alpha=0.3)
    left.set_ylabel(f"{axis} {what} ({unit})")
    right.plot([], [], color=HEATING_COLOUR, label="heating (temperature rising)")
    right.plot([], [], color=COOLING_COLOUR, label="cooling (temperature falling)")
    fig.legend(loc="outside lower center", ncol=2, fontsize=9)
    fig.suptitle(f"{run}, {axis} against {sensor}: heating and cooling paths")
    return fig


def protocol_matrix(train_labels: Sequence[str], test_labels: Sequence[str],
                    values: np.ndarray, metric: str,
                    spread: np.ndarray | None = None) -> Figure:
    """Heat map of a train-protocol × test-protocol error matrix, each cell written out (with
    ``± spread``, the standard deviation over repeats, when given)."""
    values = np.asarray(values, dtype=float)
    fig = Figure(figsize=(1.6 * len(test_labels) + 3.5, 1.0 * len(train_labels) + 2.5),
                 layout="constrained")
    ax = fig.add_subplot()
    finite = values[np.isfinite(values)]
    norm = Normalize(vmin=float(finite.min()) if finite.size else 0.0,
                     vmax=float(finite.max()) if finite.size else 1.0)
    image = ax.imshow(values, cmap="viridis_r", norm=norm, aspect="auto")
    cbar = fig.colorbar(image, ax=ax)
    cbar.set_label(metric)
    ax.set_xticks(range(len(test_labels)), test_labels, rotation=30, ha="right")
    ax.set_yticks(range(len(train_labels)), train_labels)
    ax.set_xlabel("judged on protocol")
    ax.set_ylabel("trained on protocol")
    middle = (norm.vmin + norm.vmax) / 2
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            v = values[i, j]
            text = "—" if not np.isfinite(v) else f"{v:.2f}"
            if spread is not None and np.isfinite(v) and np.isfinite(spread[i, j]):
                text += f"\n± {spread[i, j]:.2f}"
            ax.text(j, i, text, ha="center", va="center", fontsize=10,
                    color="white" if np.isfinite(v) and v > middle else "black")
    ax.set_title("Which test protocol builds a model that holds on the others")
    return fig
