"""What a metrologist reads off a model: its equation with uncertainties, the thermal drift
figures of ISO 230-3, and the wiring sheet. Plain numbers (no plotting), used by the report.

Uncertainty: the standard error of each coefficient from the least-squares fit on the training
runs, s·sqrt(diag((AᵀA)⁻¹)) with s² = RSS/(n − p). Thermal residuals are strongly
autocorrelated, so the plain OLS error is optimistic; beside it the report gives the error
inflated for AR(1) residuals, by sqrt((1 + ρ)/(1 − ρ)) with ρ the lag-1 autocorrelation of the
residual (the effective number of independent samples is n(1 − ρ)/(1 + ρ)).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from contract.terms import Term
from contract.tilt import unit_text
from host.fitting import NO_REFERENCE, Reference, design_matrix
from host.io import Run

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


def coefficient_table(axis_name: str, axis: Mapping, runs: Sequence[Run], period_s: float,
                      units: Mapping[str, str] | None = None,
                      reference: Reference = NO_REFERENCE) -> dict:
    """Coefficients of one axis with their standard errors on ``runs`` (its training runs),
    the VIF and condition number training recorded, and the equation as paper 000 prints it.

    With a ``reference`` (``start``: the model predicts the change since the run's start) the
    fit's columns are referenced the same way per run; the intercept then cancels and has no
    standard error."""
    terms = [Term.from_json(t) for t in axis["terms"]]
    coefs = np.array([float(t["coef"]) for t in axis["terms"]], dtype=float)
    intercept = float(axis["intercept"])
    metrics = axis.get("metrics") or {}
    vif = metrics.get("vif") or {}
    have = [r for r in runs if axis_name in r.target_names]
    se = se_ar1 = [math.nan] * (len(terms) + 1)
    n, rho = 0, math.nan
    if have:
        def ref(m: np.ndarray) -> np.ndarray:
            if reference.kind == "none":
                return m
            return np.column_stack([reference.apply(m[:, k]) for k in range(m.shape[1])])

        blocks = [np.column_stack([np.ones(r.n_samples),
                                   design_matrix(terms, r.columns(), period_s),
                                   r.target(axis_name)]) for r in have]
        data = np.vstack([ref(b) for b in blocks])
        A, y = data[:, :-1], data[:, -1]
        resid = y - A @ np.concatenate([[intercept], coefs])
        if reference.kind != "none":
            A = A[:, 1:]  # referenced: the intercept column is zero
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
            for r in have:
                e = resid[start:start + r.n_samples]
                e = e - e.mean()
                num += float(e[1:] @ e[:-1])
                den += float(e @ e)
                start += r.n_samples
            rho = num / den if den > 0 else 0.0
            inflate = math.sqrt((1 + rho) / (1 - rho)) if -1 < rho < 1 else math.inf
            se_ar1 = [v * inflate for v in se]
    out = unit_text(axis_name)
    rows = [{"term": "intercept", "symbol": "C₀", "coef": intercept, "unit": out,
             "se": se[0], "se_ar1": se_ar1[0], "vif": None}]
    for k, (term, c) in enumerate(zip(terms, coefs, strict=True), start=1):
        rows.append({"term": term.name, "symbol": term_symbol(term), "coef": float(c),
                     "unit": term_unit(term, units, out), "se": se[k], "se_ar1": se_ar1[k],
                     "vif": vif.get(term.name)})
    return {"axis": axis_name, "rows": rows, "n_samples": n, "residual_lag1": rho,
            "condition_number": metrics.get("condition_number"),
            "equation": equation(axis_name, rows)}


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
