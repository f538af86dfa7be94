"""What a metrologist reads off a model: its equation with uncertainties, the thermal drift
figures of ISO 230-3, and the wiring sheet. Plain numbers (no plotting), used by the report.

Uncertainty: the standard error of each coefficient from the least-squares fit on the training
runs, s·sqrt(diag((AᵀA)⁻¹)) with s² = RSS/(n − p). Thermal residuals are strongly
autocorrelated, so the plain OLS error is optimistic; beside it the report gives the error
inflated for AR(1) residuals, by sqrt((1 + ρ)/(1 − ρ)) with ρ the lag-1 autocorrelation of the
residual (the effective number of independent samples is n(1 − ρ)/(1 + ρ)).

Standard errors and VIF describe a least-squares fit only (``fit.family`` ``ols`` or
``baseline``, or a model without a ``fit``). A ridge's coefficients are shrunk on purpose, so
they are biased and the OLS formulas do not apply; for it the table gives the effective
degrees of freedom (the trace of the hat matrix) and, for either family, the spread of each
sensor's gain across folds.

Per sensor, a step of 1 K on it moves the axis by g(t) = g₀ + Σ_τ A_τ·(1 − e^(−t/τ)): a lag
term of coefficient c adds A_τ = c, a rate term (x − lag(x)) adds c to g₀ and −c to A_τ, so
it settles to nothing. The steady-state gain g(∞) = the sum of its temperature and lag
coefficients is the number a metrologist compares with the machine's expansion (µm/K).

The fold spread refits the model's own terms (its structure held fixed, the same family, for a
ridge the penalty training chose) without each fold of host train's nested validation
(host.fitting.fold_groups: one training run left out at a time, or three time blocks of a
single run) on the training runs model.json names, read here; host train's nested folds
refit the whole pipeline, whose sensors differ from fold to fold, so they have no per-sensor
gain to report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.terms import KELVIN_KINDS, Term
from thermal_comp.contract.tilt import unit_text
from thermal_comp.host.fitting import (
    DEFAULT_BLOCKS,
    NO_REFERENCE,
    Reference,
    coefficient_terms,
    design_matrix,
    fit_linear,
    fold_groups,
)
from thermal_comp.host.fitting.prefilter import prefiltered
from thermal_comp.host.fitting.ridge import column_scale, penalty_shape
from thermal_comp.host.fitting.validation import run_labels
from thermal_comp.host.io import Run

FIRST_HOUR_S = 3600.0


def term_unit(term: Term, units: Mapping[str, str] | None = None, out: str = "µm") -> str:
    """The unit of a coefficient of ``term`` (``out``: the axis's, µm or µrad for a tilt)."""
    if term.kind in ("temp", "lag", "rate"):
        return f"{out}/K"
    if term.kind == "square":
        return f"{out}/K²"
    if term.kind == "time":
        return f"{out}/s"
    unit = (units or {}).get(str(term.source), "") or "unit"
    return f"{out}/{unit}" if term.kind == "speed" else f"{out}/{unit}²"


def term_symbol(term: Term) -> str:
    """How the term reads in the equation: T05, lag₁₈₀₀(T05), rate₃₀₀(T05), (T05 − 27.1)²."""
    p = term.params
    if term.kind == "temp":
        return str(term.source)
    if term.kind in ("lag", "rate"):
        return f"{term.kind}[τ={p['tau_s']:g} s]({term.source})"
    if term.kind == "square":
        return f"({term.source} − {p['ref_c']:.4g} °C)²"
    if term.kind == "speed":
        return str(term.source)
    if term.kind == "speed2":
        return f"{term.source}²"
    return "t"


# fit families fitted by plain least squares (host.train.nested.FAMILIES); a model without a
# ``fit`` record predates the ridge and is least squares too
LEAST_SQUARES_FAMILIES = ("ols", "baseline")
# a VIF this large: the term's variance is a thousand times what it would be alone, so the data
# determine only a combination of the collinear terms, not the term
VIF_NOT_IDENTIFIABLE = 1000.0
NOT_IDENTIFIABLE = "not identifiable"
SIGN_UNDETERMINED = "gain sign undetermined"


def fit_family(axis: Mapping) -> str:
    """The axis's fit family as training recorded it (``ols`` for a model without one)."""
    return str((axis.get("fit") or {}).get("family") or "ols")


def is_least_squares(axis: Mapping) -> bool:
    """Whether the axis was fitted by plain least squares: where standard errors and VIF mean
    what their formulas say."""
    return not fit_family(axis).startswith("ridge")


@dataclass(frozen=True)
class TrainingDesign:
    """An axis's term columns and target on its training runs, referenced like the model's
    output, with host train's nested folds (fold_groups) and each run's length."""

    X: np.ndarray
    y: np.ndarray
    lengths: list[int]
    groups: np.ndarray
    scheme: str


def training_design(axis_name: str, terms: Sequence[Term], runs: Sequence[Run], period_s: float,
                    reference: Reference = NO_REFERENCE) -> TrainingDesign | None:
    have = [r for r in runs if axis_name in r.target_names]
    if not have:
        return None
    X = np.vstack([design_matrix(list(terms), r.columns(), period_s) for r in have])
    y = np.concatenate([r.target(axis_name) for r in have])
    labels = run_labels(have)
    groups, scheme = fold_groups(have, DEFAULT_BLOCKS)
    return TrainingDesign(reference.apply(X, labels), reference.apply(y, labels),
                          [r.n_samples for r in have], groups, scheme)


@dataclass(frozen=True)
class Refit:
    coef: np.ndarray
    intercept: float
    effective_dof: float  # trace of the hat matrix, intercept included


def ridge_refit(X: np.ndarray, y: np.ndarray, alpha: float, shared: Sequence[bool],
                even: Sequence[bool] | None = None, even_penalty: float = 0.0) -> Refit:
    """host.fitting.fit_ridge's solution at a fixed ``alpha`` (penalty alpha·n on the scaled
    coefficients, intercept free) on the rows it is fitted to, with its effective degrees of
    freedom tr(H), H = D(DᵀD + P)⁻¹Dᵀ = tr((DᵀD + P)⁻¹DᵀD)."""
    n, p = X.shape
    mean = X.mean(axis=0) if p else np.zeros(0)
    sd = column_scale(X, shared)
    D = np.column_stack([np.ones(n), (X - mean) / sd])
    M = D.T @ D
    shape = penalty_shape(p, even, even_penalty)
    P = (np.eye(p + 1) if shape is None else shape) * (alpha * n)
    P[0, :] = 0.0
    P[:, 0] = 0.0
    try:
        inv_m = np.linalg.solve(M + P, np.column_stack([D.T @ y, M]))
    except np.linalg.LinAlgError:
        inv_m = np.linalg.lstsq(M + P, np.column_stack([D.T @ y, M]), rcond=None)[0]
    b = inv_m[:, 0]
    coef = b[1:] / sd
    return Refit(coef, float(b[0] - (mean / sd) @ b[1:]), float(np.trace(inv_m[:, 1:])))


def axis_refit(axis: Mapping, terms: Sequence[Term], d: TrainingDesign, period_s: float,
               rows: np.ndarray | None = None) -> Refit:
    """The axis's own terms refitted on ``rows`` of its training design (all when None) the way
    training fitted them: least squares, or the ridge at the penalty it chose, on the rows
    low-passed by its prefilter and with its even-warming penalty."""
    fit = axis.get("fit") or {}
    X, y = d.X, d.y
    if not is_least_squares(axis):
        tau = float(fit.get("prefilter_tau_s") or 0.0)
        if tau > 0:
            X, y = prefiltered(X, y, d.lengths, period_s, tau)
    if rows is not None:
        X, y = X[rows], y[rows]
    if is_least_squares(axis):
        lin = fit_linear(X, y)
        return Refit(lin.coef, lin.intercept, float(np.linalg.matrix_rank(
            np.column_stack([np.ones(len(X)), X])) if len(X) else 0.0))
    penalty = float(fit.get("even_warming_penalty") or 0.0)
    return ridge_refit(X, y, float(fit.get("alpha") or 0.0),
                       [t.kind in KELVIN_KINDS for t in terms],
                       [t.kind in ("temp", "lag") for t in terms] if penalty else None, penalty)


def sensor_gains(terms: Sequence[Term], coefs: Sequence[float]) -> list[dict]:
    """Per sensor, in term order: its response to a 1 K step, g(t) = g₀ + Σ A_τ(1 − e^(−t/τ)):
    ``immediate_um_per_k`` g₀ (temperature and rate coefficients), ``modes`` the A_τ by time
    constant (a lag's coefficient, minus a rate's), ``steady_um_per_k`` g(∞) (temperature and
    lag coefficients: a rate settles to nothing) and ``curvature`` the square terms
    (coefficient in µm/K² about their reference temperature: the gain there is g(∞))."""
    out: dict[str, dict] = {}
    for term, c in zip(terms, coefs, strict=True):
        if term.kind not in ("temp", "lag", "rate", "square") or term.source is None:
            continue
        g = out.setdefault(str(term.source), {"sensor": str(term.source), "immediate": 0.0,
                                              "modes": {}, "curvature": []})
        c = float(c)
        if term.kind == "temp":
            g["immediate"] += c
        elif term.kind == "square":
            g["curvature"].append({"ref_c": float(term.params["ref_c"]), "coef": c})
        else:
            tau = float(term.params["tau_s"])
            g["immediate"] += c if term.kind == "rate" else 0.0
            g["modes"][tau] = g["modes"].get(tau, 0.0) + (c if term.kind == "lag" else -c)
    rows = []
    for g in out.values():
        modes = [{"tau_s": tau, "amplitude_um_per_k": a} for tau, a in sorted(g["modes"].items())]
        rows.append({"sensor": g["sensor"], "immediate_um_per_k": g["immediate"],
                     "steady_um_per_k": g["immediate"] + sum(m["amplitude_um_per_k"]
                                                            for m in modes),
                     "modes": modes, "curvature": g["curvature"]})
    return rows


def _steady(terms: Sequence[Term], coefs: Sequence[float]) -> dict[str, float]:
    return {g["sensor"]: g["steady_um_per_k"] for g in sensor_gains(terms, coefs)}


def _refits(axis: Mapping, terms: Sequence[Term], coefs: np.ndarray, d: TrainingDesign,
            period_s: float) -> tuple[list[dict[str, float]], float, float]:
    """The fit done again on the training design: each sensor's steady gain without each
    fold, the whole refit's largest difference from the file's coefficients (relative), and
    its effective degrees of freedom."""
    whole = axis_refit(axis, terms, d, period_s)
    edf = whole.effective_dof
    scale = max(float(np.max(np.abs(coefs))) if coefs.size else 0.0, 1e-12)
    refit_diff = (float(np.max(np.abs(whole.coef - coefs))) / scale) if coefs.size else 0.0
    folds = []
    for g in np.unique(d.groups):
        rows = d.groups != g
        if rows.sum() > len(terms) + 1:
            folds.append(_steady(terms, axis_refit(axis, terms, d, period_s, rows).coef))
    return folds, refit_diff, edf


def _standard_errors(d: TrainingDesign, coefs: np.ndarray, intercept: float, reference: Reference,
                     se: list[float], se_ar1: list[float]
                     ) -> tuple[list[float], list[float], int, float]:
    """A least-squares fit's standard errors on its training design, and the same inflated
    for the residuals' lag-1 autocorrelation within each run: (se, se_ar1, samples, rho).
    ``se``/``se_ar1`` come back unchanged when there are no more samples than columns."""
    rho = math.nan
    if reference.kind != "none":  # referenced: the intercept cancels, its column is zero
        A = d.X
        resid = d.y - A @ coefs
    else:
        A = np.column_stack([np.ones(len(d.y)), d.X])
        resid = d.y - A @ np.concatenate([[intercept], coefs])
    n, p = A.shape
    if n > p:
        s2 = float(resid @ resid) / (n - p)
        cov = s2 * np.linalg.pinv(A.T @ A)
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None)).tolist()
        if reference.kind != "none":
            se = [math.nan, *se]
        # lag-1 autocorrelation within each run (the filters restart at each run's start)
        num = den = 0.0
        start = 0
        for length in d.lengths:
            e = resid[start:start + length]
            e = e - e.mean()
            num += float(e[1:] @ e[:-1])
            den += float(e @ e)
            start += length
        rho = num / den if den > 0 else 0.0
        inflate = math.sqrt((1 + rho) / (1 - rho)) if -1 < rho < 1 else math.inf
        se_ar1 = [v * inflate for v in se]
    return se, se_ar1, n, rho


def coefficient_table(axis_name: str, axis: Mapping, runs: Sequence[Run], period_s: float,
                      units: Mapping[str, str] | None = None,
                      reference: Reference = NO_REFERENCE) -> dict:
    """What a metrologist reads off one axis: per sensor its steady-state gain, its dynamics
    as time constants and the gain's spread across folds; the equation term by term; and
    only for a least-squares fit the coefficients' standard errors on ``runs`` (its training
    runs), the VIF and condition number training recorded; for a ridge its effective degrees
    of freedom. ``warnings`` names a fit that is not identifiable.

    With a ``reference`` (``start``: the model predicts the change since the run's start) the
    fit's columns are referenced the same way per run; the intercept then cancels and has no
    standard error. Without ``runs`` (not readable here) only what the model file holds."""
    terms, coefs = coefficient_terms(axis["terms"])
    intercept = float(axis["intercept"])
    metrics = axis.get("metrics") or {}
    fit = axis.get("fit") or {}
    least_squares = is_least_squares(axis)
    vif = (metrics.get("vif") or {}) if least_squares else {}
    se = se_ar1 = [math.nan] * (len(terms) + 1)
    n, rho = 0, math.nan
    d = training_design(axis_name, terms, runs, period_s, reference)
    folds: list[dict[str, float]] = []
    refit_diff = edf = math.nan
    if d is not None:
        folds, refit_diff, edf = _refits(axis, terms, coefs, d, period_s)
    if d is not None and least_squares:
        se, se_ar1, n, rho = _standard_errors(d, coefs, intercept, reference, se, se_ar1)
    out = unit_text(axis_name)
    rows = [{"term": "intercept", "symbol": "C₀", "coef": intercept, "unit": out,
             "se": se[0], "se_ar1": se_ar1[0], "vif": None}]
    for k, (term, c) in enumerate(zip(terms, coefs, strict=True), start=1):
        rows.append({"term": term.name, "symbol": term_symbol(term), "coef": float(c),
                     "unit": term_unit(term, units, out), "se": se[k], "se_ar1": se_ar1[k],
                     "vif": vif.get(term.name)})
    gains = sensor_gains(terms, coefs)
    for g in gains:
        g["fold_steady_um_per_k"] = [f[g["sensor"]] for f in folds if g["sensor"] in f]
    even = {"steady_um_per_k": float(sum(g["steady_um_per_k"] for g in gains)),
            "fold_steady_um_per_k": [float(sum(f.values())) for f in folds]}
    other = [r for r, t in zip(rows[1:], terms, strict=True)
             if t.kind not in ("temp", "lag", "rate", "square")]
    table = {"axis": axis_name, "family": fit_family(axis), "least_squares": least_squares,
             "alpha": None if least_squares else fit.get("alpha"),
             "rows": rows, "n_samples": n if least_squares else (len(d.y) if d else 0),
             "n_coefficients": len(terms) + 1, "effective_dof": edf,
             "residual_lag1": rho,
             "condition_number": metrics.get("condition_number") if least_squares else None,
             "max_vif": max(vif.values()) if vif else None,
             "sensors": gains, "even_warming": even, "other_terms": other,
             "taus_s": sorted({m["tau_s"] for g in gains for m in g["modes"]}),
             "folds": {"scheme": d.scheme if d else None, "count": len(folds)},
             "refit_relative_difference": refit_diff,
             "unit": out, "curved": any(g["curvature"] for g in gains),
             "equation": equation(axis_name, rows)}
    table["warnings"] = identifiability(table)
    return table


def identifiability(table: Mapping) -> list[dict]:
    """Named warnings for a fit whose numbers cannot be read one by one: ``not identifiable``
    (least squares: every coefficient smaller than its AR(1) standard error, or a VIF of
    VIF_NOT_IDENTIFIABLE or more; either family: no sensor's gain keeps its sign across the
    folds) and ``gain sign undetermined`` (some sensors' gains change sign between folds, or
    differ in sign from the whole training's)."""
    out: list[dict] = []
    if table["least_squares"]:
        judged = [r for r in table["rows"] if math.isfinite(r["se_ar1"])]
        if judged and all(abs(r["coef"]) < r["se_ar1"] for r in judged):
            worst = max(judged, key=lambda r: r["se_ar1"] / max(abs(r["coef"]), 1e-300))
            out.append({"name": NOT_IDENTIFIABLE, "text": (
                "every coefficient is smaller than its standard error (AR(1)), e.g. "
                f"{worst['term']} {worst['coef']:.3g} ± {worst['se_ar1']:.3g} {worst['unit']}: "
                "the training data do not determine any single term")})
        vifs = [(r["vif"], r["term"]) for r in table["rows"] if r["vif"] is not None]
        if vifs and max(vifs)[0] >= VIF_NOT_IDENTIFIABLE:
            v, term = max(vifs)
            many = sum(1 for x, _ in vifs if x >= VIF_NOT_IDENTIFIABLE)
            out.append({"name": NOT_IDENTIFIABLE, "text": (
                f"VIF up to {v:,.0f} ({term}; {many} of {len(vifs)} terms at "
                f"{VIF_NOT_IDENTIFIABLE:,.0f} or more): these terms are near-copies of one "
                "another, so the data fix only their combination; a single coefficient can "
                "take almost any value")})
    judged = [g for g in table["sensors"] if len(g["fold_steady_um_per_k"]) >= 2]
    flips = [g["sensor"] for g in judged
             if min(g["steady_um_per_k"], *g["fold_steady_um_per_k"]) < 0
             < max(g["steady_um_per_k"], *g["fold_steady_um_per_k"])]
    if judged and len(flips) == len(judged):
        out.append({"name": NOT_IDENTIFIABLE, "text": (
            "no sensor's steady-state gain keeps its sign across the folds: the gains "
            "cannot be read as the machine's sensitivity to each temperature")})
    elif flips:
        out.append({"name": SIGN_UNDETERMINED, "text": (
            f"the steady-state gain of {', '.join(flips)} changes sign between folds (or "
            "against the whole training's): "
            "its sign, let alone its size, is not determined by the training data")})
    return out


def equation(axis_name: str, rows: Sequence[Mapping]) -> str:
    """``δ_dz = 12.3(±0.4) + 1.23(±0.02)·T05 − ...`` with the AR(1) standard errors."""
    def num(v: float, se: float) -> str:
        digits = 3 if not math.isfinite(se) or se <= 0 else max(
            0, min(6, 1 - int(math.floor(math.log10(se)))))
        text = f"{abs(v):.{digits}f}"
        return text + (f"(±{se:.{digits}f})" if math.isfinite(se) else "")

    parts = [("−" if rows[0]["coef"] < 0 else "") + num(rows[0]["coef"], rows[0]["se_ar1"])]
    for r in rows[1:]:
        sign = "−" if r["coef"] < 0 else "+"
        parts.append(f"{sign} {num(r['coef'], r['se_ar1'])}·{r['symbol']}")
    return f"δ({axis_name}) = " + " ".join(parts)


def iso230_drift(time_s: np.ndarray, displacement: np.ndarray) -> dict:
    """ISO 230-3 style thermal drift of one axis over a run (µm): the largest drift (range of
    the displacement over the whole test), the largest drift within the first hour, and the
    change from start to end of the test."""
    t = np.asarray(time_s, dtype=float)
    y = np.asarray(displacement, dtype=float)
    if not len(y):
        return {"max_um": None, "first_hour_um": None, "start_to_end_um": None}
    first = t <= t[0] + FIRST_HOUR_S
    return {"max_um": float(np.ptp(y)), "first_hour_um": float(np.ptp(y[first])),
            "start_to_end_um": float(y[-1] - y[0]),
            "hours": float((t[-1] - t[0]) / 3600.0)}


def wiring_rows(model: Mapping, locations: Mapping[str, str] | None = None) -> list[dict]:
    """The wiring sheet: box channel → sensor → thermocouple type → where on the machine
    (when given) → the axes that read it and its training range."""
    readers: dict[str, list[str]] = {}
    for name, axis in model["axes"].items():
        for t in axis["terms"]:
            if t.get("source") and name not in readers.setdefault(t["source"], []):
                readers[t["source"]].append(name)
    rows = []
    for c in sorted(model["channels"], key=lambda c: int(c["channel"])):
        rows.append({"channel": int(c["channel"]), "sensor": c["sensor"],
                     "tc_type": c.get("tc_type", "K"),
                     "location": (locations or {}).get(c["sensor"]),
                     "axes": readers.get(c["sensor"], []),
                     "trained_min_c": c.get("trained_min_c"),
                     "trained_max_c": c.get("trained_max_c"),
                     "valid_c": (c.get("min_c"), c.get("max_c"))})
    return rows
