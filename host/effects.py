"""Close the loop (issue 7): find what the validation residual lacks and add it, validated.

A static model delta = C0 + sum Ci*Ti (paper 000) cannot represent thermal lag (pseudo-
hysteresis), ambient drift, speed-dependent growth, a slow trend or a nonlinear rise. Each of
those has a small family of extra terms the box computes causally (host/terms.py, all in the
fixed-point contract). Starting from the baseline selection, ``search_effects``:

1. takes the *out-of-fold* residual of the current model (leave-one-run-out, or contiguous
   time blocks of one run: host/validation.py), never the training residual alone;
2. scores every candidate family: its partial correlation with that residual (evidence only)
   and the out-of-fold RMSE of the current terms plus the family, per fold and overall; the
   families of a measured input (shop air, spindle speed) are also scored with the sensors
   re-selected given that input, because a static selection picks stand-ins for an input
   (``reselected_candidates``), and must then also beat the re-selected sensors alone;
3. adds the best candidate only if it is material and stable (the rule, ``passes``): at least
   ``MIN_GAIN`` (10 %) lower validation RMSE *and* a lower held-out RMSE in every fold. The
   thresholds are fixed a priori for unseen runs, not tuned to a dataset;
4. refuses a candidate the box could not run within the codegen error bound (the lag state
   quantisation bound grows as 1/alpha, so long time constants with large coefficients can
   break the 0.01 um default) and takes the next passing one instead;
5. refits and repeats, at most ``MAX_EFFECTS`` (3) times.

When no candidate passes and the residual is still structured (lag-1 autocorrelation well
above white noise *and* RMSE well above the measurement noise floor), the report says so
(``unexplained``) instead of forcing a term. docs/effects.md explains every choice.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from host.data import Run
from host.fit import fit_linear, rmse
from host.selection import DEFAULT_GROUPS, DEFAULT_MAX_SENSORS, select_sensors
from host.terms import (
    ALPHA_FRAC_BITS,
    Term,
    make_lag,
    make_rate,
    make_speed,
    make_square,
    make_temp,
    make_time,
    term_values,
)
from host.validation import DEFAULT_BLOCKS, fold_groups

EFFECT_KINDS = ("lag", "rate", "ambient", "speed", "drift", "nonlinear")
# Time constants tried for lag/rate/ambient: minutes to hours. The longest (4 h) keeps the
# state-quantisation bound (0.5/alpha state units) small at the usual sample periods (>= 1 s);
# a model that would still break the codegen bound is refused candidate by candidate.
TAU_GRID_S = (300.0, 600.0, 1200.0, 1800.0, 3600.0, 7200.0, 14400.0)
MIN_TAU_SAMPLES = 3  # a filter faster than three samples is the sensor itself
MAX_TAU_RUN_FRACTION = 0.25  # a run must span 4 time constants (98 % settled) to identify one
MIN_GAIN = 0.10  # an effect must lower the validation RMSE by at least 10 %
MIN_FOLD_GAIN = 0.0  # ... and every fold's held-out RMSE lower
ACTIVE_SHARE = 0.1  # a fold exercises an effect if its contribution varies there (SD >= 10 %)
MAX_IDLE_LOSS = 0.05  # a fold that does not exercise it may get at most 5 % worse
MAX_FOLD_SPREAD = 1.0  # the effect fitted without a fold keeps its shape (RMS change < size)
PARSIMONY = 0.01  # a candidate with fewer terms within 1 % of the best is preferred
MAX_EFFECTS = 3
MAX_SEARCH_ROWS = 20_000  # the search scores at most about this many samples (search_stride)
# Families of a measured input (shop air, spindle speed): the static selection may have picked
# stand-ins for them, so they are also tried with the sensors re-selected (docs/effects.md).
INPUT_KINDS = ("ambient", "speed")
MAX_ERROR_UM = 0.01  # codegen's default --max-error-um
STATE_SHARE = 0.75  # share of the codegen bound the filter states may use
FINAL_ROUNDING_UM = 0.0005
AUTOCORR_LIMIT = 0.5  # lag-1 autocorrelation above which a residual is "structured"
NOISE_MULTIPLE = 3.0  # ... provided its RMSE is also above this multiple of the noise floor
AMBIENT_PATTERNS = ("*amb*", "*AMB*", "*Amb*")
TOP_RECORDED = 5  # candidates kept per step in the report


class EffectsError(ValueError):
    """The effect search cannot run on these inputs (names the column or parameter)."""


# ------------------------------------------------------------------ candidates


@dataclass(frozen=True)
class Candidate:
    """One effect family: terms to add (and, for a swap, terms to remove).

    ``family`` is set when the candidate also re-selects the temperature sensors (an input's
    family, see ``reselected_candidates``): ``add`` then holds the family *and* the newly
    selected sensors, ``remove`` the sensors the re-selection gave up, and the effect itself
    (its evidence, its contribution) is ``family`` alone.
    """

    kind: str
    add: tuple[Term, ...]
    remove: tuple[Term, ...] = ()
    family: tuple[Term, ...] = ()

    @property
    def effect_terms(self) -> tuple[Term, ...]:
        return self.family or self.add

    @property
    def n_terms(self) -> int:
        """Terms the model gains (a re-selection may also give some up)."""
        return len(self.add) - len(self.remove)

    @property
    def feature(self) -> str:
        if self.family:
            moved = ([f"+{t.source}" for t in self.add if t not in self.family]
                     + [f"-{t.source}" for t in self.remove])
            return (f"{' + '.join(t.name for t in self.family)} "
                    f"(sensors re-selected: {', '.join(moved)})")
        text = " + ".join(t.name for t in self.add)
        if self.remove:
            text = f"{text} instead of {' + '.join(t.name for t in self.remove)}"
        return text

    def apply(self, terms: Sequence[Term]) -> list[Term]:
        return [t for t in terms if t not in self.remove] + [t for t in self.add
                                                              if t not in terms]


def find_ambient(sensor_names: Sequence[str], ambient: str | None = None) -> str | None:
    """The ambient sensor: the one given (must be a sensor column), else a name like *amb*."""
    if ambient is not None:
        if ambient not in sensor_names:
            raise EffectsError(f"--ambient {ambient}: not one of the temperature columns "
                               f"({', '.join(sensor_names)}); make --sensors include it")
        return ambient
    for name in sensor_names:
        if any(fnmatch.fnmatchcase(name, p) for p in AMBIENT_PATTERNS):
            return name
    return None


def tau_grid(period_s: float, shortest_run_s: float,
             taus: Iterable[float] = TAU_GRID_S) -> list[float]:
    """Time constants that are identifiable at this period and run length."""
    return [float(t) for t in taus
            if t >= MIN_TAU_SAMPLES * period_s and t <= MAX_TAU_RUN_FRACTION * shortest_run_s]


def start_reference(runs: Sequence[Run], sensor: str) -> float:
    """Reference of a ``square`` term: the median start temperature of the runs."""
    return float(np.median([r.column(sensor)[0] for r in runs]))


def generate_candidates(current: Sequence[Term], sensors: Sequence[str], aux: Sequence[str],
                        ambient: str | None, period_s: float, taus: Sequence[float],
                        square_refs: Mapping[str, float]) -> list[Candidate]:
    """Every effect family the box can compute, given the current terms.

    - lag: lag(s, tau) of every sensor (a selected sensor's own lag models its pseudo-
      hysteresis; another sensor's lag stands in for an unmeasured part);
    - rate: rate(s, tau) of sensors whose temperature is not a term (for those that are,
      rate = T - lag spans the same model as lag and is reported as lag);
    - ambient: the ambient sensor, its lag (the frame follows the air through a first-order
      lag), and both (a part that follows the air at once plus one that lags);
    - speed: n, and n with n^2, of every aux input (no lag: immediate growth);
    - drift: a slow trend (``time``);
    - nonlinear: (T - T_start)^2 of a sensor that is a term, or T and (T - T_start)^2 of one
      that is not.
    """
    have = set(current)
    temps = {t.source for t in current if t.kind == "temp"}
    out: list[Candidate] = []

    def add(kind: str, *terms: Term) -> None:
        if not any(t in have for t in terms):
            out.append(Candidate(kind, tuple(terms)))

    for s in sensors:
        if s == ambient:
            continue
        for tau in taus:
            add("lag", make_lag(s, tau, period_s))
        if s not in temps:
            for tau in taus:
                add("rate", make_rate(s, tau, period_s))
    if ambient is not None:
        if ambient not in temps:
            add("ambient", make_temp(ambient))
            for tau in taus:
                add("ambient", make_temp(ambient), make_lag(ambient, tau, period_s))
        else:
            for tau in taus:
                add("ambient", make_lag(ambient, tau, period_s))
    for n in aux:
        add("speed", make_speed(n))
        add("speed", make_speed(n), make_speed(n, squared=True))
    add("drift", make_time())
    for s in sensors:
        if s == ambient or s not in square_refs:
            continue
        if s in temps:
            add("nonlinear", make_square(s, square_refs[s]))
        else:
            add("nonlinear", make_temp(s), make_square(s, square_refs[s]))
    return out


# ------------------------------------------------------------------ scoring


def search_stride(runs: Sequence[Run], max_rows: int = MAX_SEARCH_ROWS) -> int:
    """Every how-many-th sample the search scores, so it sees at most about ``max_rows``.

    Thermal signals change over minutes; a 24 h run at 1 s has far more rows than the
    comparison of candidates needs, and scoring ~1000 candidate columns at full rate costs
    gigabytes. Features are still computed at the full rate (filters run on every sample, as
    on the box) and the final model is refitted on every sample (host.train.fit_axis).
    """
    return max(1, math.ceil(sum(r.n_samples for r in runs) / max_rows))


def every_nth(runs: Sequence[Run], stride: int, values: np.ndarray) -> np.ndarray:
    """Keep every ``stride``-th row of each run within stacked per-sample ``values``."""
    keep, offset = [], 0
    for r in runs:
        keep.append(offset + np.arange(0, r.n_samples, stride))
        offset += r.n_samples
    return values[np.concatenate(keep)]


class FeatureCache:
    """Term values on every run, stacked, each computed once (filters run per whole run)."""

    def __init__(self, runs: Sequence[Run], period_s: float, stride: int = 1) -> None:
        self.columns = [r.columns() for r in runs]
        self.period_s = period_s
        self.stride = stride
        self._cache: dict[Term, np.ndarray] = {}

    def column(self, term: Term) -> np.ndarray:
        if term not in self._cache:
            self._cache[term] = np.concatenate(
                [term_values(term, cols, self.period_s)[::self.stride] for cols in self.columns])
        return self._cache[term]

    def matrix(self, terms: Sequence[Term]) -> np.ndarray:
        n = sum(len(c["time_s"][::self.stride]) for c in self.columns)
        if not terms:
            return np.empty((n, 0))
        return np.column_stack([self.column(t) for t in terms])


@dataclass(frozen=True)
class Rule:
    """When an effect is material and stable enough to add.

    ``min_gain``: validation RMSE (all out-of-fold predictions) at least this much lower;
    ``min_fold_gain``: and every fold's held-out RMSE lower by more than this -- every fold
    that exercises the effect (its contribution's SD there is at least ``ACTIVE_SHARE`` of
    its SD overall; at least two folds must): a fold without it (the spindle-speed term while
    the spindle stands still) is no evidence either way and may only not get materially worse
    (``max_idle_loss``);
    ``max_fold_spread``: and the effect fitted without any one fold the same effect (its
    contribution changes by at most this fraction, RMS).
    """

    min_gain: float = MIN_GAIN
    min_fold_gain: float = MIN_FOLD_GAIN
    max_fold_spread: float = MAX_FOLD_SPREAD
    max_idle_loss: float = MAX_IDLE_LOSS

    def describe(self) -> str:
        fold = ("lower" if self.min_fold_gain <= 0
                else f"at least {self.min_fold_gain:.0%} lower")
        return (f">= {self.min_gain:.0%} lower validation RMSE, {fold} held-out RMSE in every "
                f"fold that exercises the effect (at least 2; others at most "
                f"{self.max_idle_loss:.0%} worse), and the same effect in every fold "
                f"(contribution spread <= {self.max_fold_spread:.0%})")


@dataclass
class Scored:
    """A model's out-of-fold performance (a candidate's, or the current model's)."""

    candidate: Candidate | None
    validation_rmse_um: float
    fold_rmse_um: np.ndarray
    residual_corr: float = math.nan
    fold_spread: float = 0.0  # RMS change of the effect's contribution without a fold
    fold_active: np.ndarray | None = None  # folds in which the effect varies at all
    codegen: str | None = None  # why the box cannot run it, if it cannot
    # a re-selected input family: the same re-selected sensors without the family, which it
    # must beat by the same rule (so a better sensor choice is never credited to the input)
    sensors_only: Scored | None = None

    def gain_over(self, ref: Scored) -> float:
        """Relative validation RMSE reduction against ``ref`` (0.1 = 10 % lower)."""
        if not ref.validation_rmse_um > 0:
            return 0.0
        return 1.0 - self.validation_rmse_um / ref.validation_rmse_um

    def folds_improved(self, ref: Scored) -> int:
        return int(np.sum(self.fold_rmse_um < ref.fold_rmse_um))

    def fold_gains(self, ref: Scored) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(ref.fold_rmse_um > 0, 1.0 - self.fold_rmse_um / ref.fold_rmse_um, 0.0)

    def active(self) -> np.ndarray:
        n = len(self.fold_rmse_um)
        return np.ones(n, dtype=bool) if self.fold_active is None else self.fold_active

    def passes(self, ref: Scored, rule: Rule | None = None) -> bool:
        """The acceptance rule (see ``Rule``); a re-selected input family must pass it both
        against the current model and against its re-selected sensors alone."""
        rule = rule or Rule()
        if self.sensors_only is not None and not self._passes(self.sensors_only, rule):
            return False
        return self._passes(ref, rule)

    def _passes(self, ref: Scored, rule: Rule) -> bool:
        gains, active = self.fold_gains(ref), self.active()
        return (self.gain_over(ref) >= rule.min_gain
                and int(active.sum()) >= min(2, active.size)
                and bool(np.all(gains[active] > rule.min_fold_gain))
                and bool(np.all(gains[~active] > -rule.max_idle_loss))
                and self.fold_spread <= rule.max_fold_spread)

    def evidence(self, ref: Scored) -> dict:
        more = {}
        if self.sensors_only is not None:
            more = {"sensors_only_rmse_um": _round(self.sensors_only.validation_rmse_um, 4),
                    "improvement_over_sensors_only_pct":
                        _round(100.0 * self.gain_over(self.sensors_only), 2),
                    "folds_improved_over_sensors_only":
                        f"{self.folds_improved(self.sensors_only)}/{len(ref.fold_rmse_um)}"}
        return {
            "residual_corr": _round(self.residual_corr, 4),
            "folds_improved": f"{self.folds_improved(ref)}/{len(ref.fold_rmse_um)}",
            "folds_exercised": f"{int(self.active().sum())}/{len(ref.fold_rmse_um)}",
            "improvement_pct": _round(100.0 * self.gain_over(ref), 2),
            "fold_rmse_before_um": [_round(v, 4) for v in ref.fold_rmse_um],
            "fold_rmse_after_um": [_round(v, 4) for v in self.fold_rmse_um],
            "fold_spread": _round(self.fold_spread, 4),
            **more,
        }


def _round(x: float, digits: int) -> float:
    return round(float(x), digits) if math.isfinite(x) else math.nan


def score(X: np.ndarray, y: np.ndarray, groups: np.ndarray, candidate: Candidate | None = None,
          n_new: int = 0) -> tuple[Scored, np.ndarray]:
    """Out-of-fold RMSE (overall and per fold) of a design, and its out-of-fold residual.

    The last ``n_new`` columns are the candidate's: their contribution fitted without each fold
    is compared with the all-data fit (``fold_spread``, the same effect in every fold?).
    """
    residual = np.empty_like(y, dtype=float)
    fold_coefs = []
    for g in np.unique(groups):
        test = groups == g
        fit = fit_linear(X[~test], y[~test])
        residual[test] = y[test] - fit.predict(X[test])
        fold_coefs.append(fit.coef[X.shape[1] - n_new:])
    folds = np.array([rmse(residual[groups == g]) for g in np.unique(groups)])
    scored = Scored(candidate, rmse(residual), folds)
    if n_new:
        Z = X[:, X.shape[1] - n_new:]
        Z = Z - Z.mean(axis=0)
        full = Z @ fit_linear(X, y).coef[X.shape[1] - n_new:]
        size = rmse(full)
        scored.fold_spread = (max(rmse(Z @ c - full) for c in fold_coefs) / size if size > 0
                              else math.inf)
        scored.fold_active = np.array([float(np.std(full[groups == g])) >= ACTIVE_SHARE * size
                                       for g in np.unique(groups)])
    return scored, residual


def partial_correlation(residual: np.ndarray, Z: np.ndarray, X: np.ndarray) -> float:
    """Correlation of the residual with the new columns Z once the current design X is removed.

    One column: signed Pearson r. Several: the multiple correlation R (>= 0).
    """
    base = np.column_stack([np.ones(len(residual)), X])
    proj, *_ = np.linalg.lstsq(base, Z, rcond=None)
    Zp = Z - base @ proj
    r = residual - residual.mean()
    if Zp.shape[1] == 1:
        z = Zp[:, 0]
        den = math.sqrt(float(z @ z) * float(r @ r))
        return float(z @ r) / den if den > 0 else 0.0
    coef, *_ = np.linalg.lstsq(Zp, r, rcond=None)
    ss = float(r @ r)
    return math.sqrt(max(0.0, 1.0 - float(np.sum((r - Zp @ coef) ** 2)) / ss)) if ss > 0 else 0.0


class GramScorer:
    """Out-of-fold least squares of any subset of columns from per-fold Gram matrices.

    The same numbers as ``score`` (refit without each fold, predict it) for hundreds of
    candidates at the cost of one pass over the data: columns are standardised once (global
    mean and SD; an intercept column keeps every fit's offset free) and each candidate only
    solves a few small normal-equation systems.
    """

    def __init__(self, A: np.ndarray, y: np.ndarray, groups: np.ndarray) -> None:
        A = np.asarray(A, dtype=float)
        y = np.asarray(y, dtype=float)
        n, p = A.shape
        sd = A.std(axis=0)
        sd[sd == 0] = 1.0
        self.D = np.empty((n, p + 1))
        self.D[:, 0] = 1.0
        np.subtract(A, A.mean(axis=0), out=self.D[:, 1:])
        self.D[:, 1:] /= sd
        self.y0 = y - y.mean()
        self.groups = np.asarray(groups)
        self.fold_ids = np.unique(self.groups)
        self.rows = [self.groups == g for g in self.fold_ids]
        self.n_f = np.array([int(r.sum()) for r in self.rows])
        self.M_f = np.array([self.D[r].T @ self.D[r] for r in self.rows])
        self.v_f = np.array([self.D[r].T @ self.y0[r] for r in self.rows])
        self.s_f = np.array([float(self.y0[r] @ self.y0[r]) for r in self.rows])
        self.M = self.M_f.sum(axis=0)
        self.v = self.v_f.sum(axis=0)
        self.n = n

    @staticmethod
    def _solve(M: np.ndarray, v: np.ndarray) -> np.ndarray:
        try:
            beta = np.linalg.solve(M, v)
            if np.all(np.isfinite(beta)) and np.allclose(M @ beta, v, rtol=1e-8,
                                                         atol=1e-10 * max(1.0, abs(v).max())):
                return beta
        except np.linalg.LinAlgError:
            pass
        return np.linalg.lstsq(M, v, rcond=None)[0]  # rank deficient: minimum norm

    def _fold_betas(self, idx: np.ndarray) -> list[np.ndarray]:
        ix = np.ix_(idx, idx)
        return [self._solve(self.M[ix] - Mf[ix], self.v[idx] - vf[idx])
                for Mf, vf in zip(self.M_f, self.v_f, strict=True)]

    def fold_sse(self, idx: np.ndarray, betas: list[np.ndarray]) -> np.ndarray:
        ix = np.ix_(idx, idx)
        return np.array([max(float(s - 2 * b @ vf[idx] + b @ Mf[ix] @ b), 0.0)
                         for b, Mf, vf, s in zip(betas, self.M_f, self.v_f, self.s_f,
                                                 strict=True)])

    def residual(self, cols: Sequence[int]) -> np.ndarray:
        """Out-of-fold residual of the columns ``cols`` (indices into A)."""
        idx = np.array([0, *(c + 1 for c in cols)], dtype=int)
        out = np.empty(self.n)
        for b, r in zip(self._fold_betas(idx), self.rows, strict=True):
            out[r] = self.y0[r] - self.D[r][:, idx] @ b
        return out

    def score(self, cols: Sequence[int], new: Sequence[int],
              candidate: Candidate | None = None) -> Scored:
        """Like ``score``: columns ``cols`` of A, of which ``new`` are the candidate's."""
        idx = np.array([0, *(c + 1 for c in cols)], dtype=int)
        betas = self._fold_betas(idx)
        sse = self.fold_sse(idx, betas)
        scored = Scored(candidate, math.sqrt(sse.sum() / self.n), np.sqrt(sse / self.n_f))
        if new:
            pos = np.array([list(cols).index(c) + 1 for c in new])
            nz = np.array([c + 1 for c in new])
            C = self.M[np.ix_(nz, nz)] / self.n  # covariance of the (centred) new columns
            full = self._solve(self.M[np.ix_(idx, idx)], self.v[idx])[pos]
            size = math.sqrt(max(float(full @ C @ full), 0.0))
            if size > 0:
                spread = max(math.sqrt(max(float((b[pos] - full) @ C @ (b[pos] - full)), 0.0))
                             for b in betas)
                scored.fold_spread = spread / size
                active = []
                for Mf, nf in zip(self.M_f, self.n_f, strict=True):
                    mean = float(Mf[0, nz] @ full) / nf
                    var = float(full @ Mf[np.ix_(nz, nz)] @ full) / nf - mean * mean
                    active.append(math.sqrt(max(var, 0.0)) >= ACTIVE_SHARE * size)
                scored.fold_active = np.array(active)
            else:
                scored.fold_spread = math.inf
        return scored

    def partial_correlation(self, residual: np.ndarray, q: np.ndarray, base: Sequence[int],
                            new: Sequence[int]) -> float:
        """``partial_correlation`` from the Gram matrix; ``q`` = D.T @ residual (once a step)."""
        b = np.array([0, *(c + 1 for c in base)], dtype=int)
        z = np.array([c + 1 for c in new], dtype=int)
        G = self.M
        P = self._solve(G[np.ix_(b, b)], G[np.ix_(b, z)])
        zr = q[z] - P.T @ q[b]
        zz = G[np.ix_(z, z)] - G[np.ix_(z, b)] @ P
        rr = float(residual @ residual) - residual.size * float(residual.mean()) ** 2
        if rr <= 0:
            return 0.0
        if z.size == 1:
            den = math.sqrt(max(float(zz[0, 0]), 0.0) * rr)
            return float(zr[0]) / den if den > 0 else 0.0
        r2 = float(zr @ self._solve(zz, zr)) / rr
        return math.sqrt(min(max(r2, 0.0), 1.0))


def score_candidates(cache: FeatureCache, y: np.ndarray, groups: np.ndarray,
                     current: Sequence[Term], candidates: Sequence[Candidate]
                     ) -> tuple[Scored, np.ndarray, list[Scored]]:
    """The current model's out-of-fold score and residual, and every candidate's score,
    sorted best (lowest validation RMSE) first."""
    terms: list[Term] = list(current)
    for cand in candidates:
        terms += [t for t in cand.add if t not in terms]
    index = {t: i for i, t in enumerate(terms)}
    gram = GramScorer(cache.matrix(terms), y, groups)
    base = [index[t] for t in current]
    ref = gram.score(base, [])
    residual = gram.residual(base)
    q = gram.D.T @ residual
    scored = []
    for cand in candidates:
        cols = [index[t] for t in cand.apply(current)]
        new = [index[t] for t in cand.effect_terms]
        s = gram.score(cols, new, cand)
        if cand.family:
            s.sensors_only = gram.score([c for c in cols if c not in new], [])
        s.residual_corr = gram.partial_correlation(residual, q, base, new)
        scored.append(s)
    scored.sort(key=lambda s: s.validation_rmse_um)
    return ref, residual, scored


def preferred(passing: Sequence[Scored]) -> list[Scored]:
    """Order passing candidates: within PARSIMONY of the best, fewer terms first; then RMSE."""
    if not passing:
        return []
    best = min(s.validation_rmse_um for s in passing)

    def key(s: Scored) -> tuple:
        assert s.candidate is not None
        near = s.validation_rmse_um <= best * (1.0 + PARSIMONY)
        return (not near, s.candidate.n_terms if near else 0, s.validation_rmse_um)

    return sorted(passing, key=key)


# ------------------------------------------------------------------ inputs: re-selection


@dataclass(frozen=True)
class Reselection:
    """How the baseline's sensors were selected, so an input's family can redo it.

    Same method and group count as host.train's selection (from its trace); ``max_sensors``
    is the most sensors a re-selection may keep.
    """

    method: str = "validated"
    n_groups: int = DEFAULT_GROUPS
    max_sensors: int = DEFAULT_MAX_SENSORS
    seed: int = 0

    @classmethod
    def from_trace(cls, trace: Mapping | None, max_sensors: int = DEFAULT_MAX_SENSORS
                   ) -> Reselection:
        trace = trace or {}
        groups = trace.get("groups") or []
        return cls(method=str(trace.get("method", "validated")),
                   n_groups=len(groups) or DEFAULT_GROUPS, max_sensors=int(max_sensors))


def input_source(cand: Candidate) -> str | None:
    """The measured input an input family is built on (the ambient sensor, an aux column)."""
    if cand.kind not in INPUT_KINDS or cand.remove or cand.family:
        return None
    return str(cand.add[0].source)


def reselected_candidates(cands: Sequence[Candidate], cache: FeatureCache, y: np.ndarray,
                          groups: np.ndarray, run_ids: np.ndarray, current: Sequence[Term],
                          sensors: Sequence[str], ambient: str | None, period_s: float,
                          scheme: str, how: Reselection, allowed_new: int,
                          baseline_sources: set[str]) -> list[Candidate]:
    """An input's family with the temperature sensors selected again, given that input.

    The air and the spindle speed reach the whole machine. A static selection, which sees
    only temperatures, therefore picks thermocouples that stand in for them (the table and
    the tank for the air's slow pull on the frame, a fast gearbox sensor for the spindle's
    speed), and adding the input's own terms to that model leaves the stand-ins in it: they
    are fitted to this run's coincidences and cost accuracy on another day. Per input
    (the ambient sensor, every aux column) this takes the variant of its family that best
    explains the target together with *every* thermocouple (no stand-in is needed there),
    removes it and the model's other effect terms from the target and the temperatures
    (Frisch-Waugh-Lovell), and runs host.selection again on what remains (same method, group
    count and sensor limit). The candidate is that family plus the re-selected sensors
    instead of the old ones; it is judged by the same rule as every other candidate. At most
    ``allowed_new`` sensors outside ``baseline_sources`` may come in (host.train's channel
    budget); the least useful newcomers are dropped until it fits.
    """
    pool = [s for s in sensors if s != ambient]
    if not pool:
        return []
    by_source: dict[str, list[Candidate]] = {}
    for c in cands:
        src = input_source(c)
        if src is not None:
            by_source.setdefault(src, []).append(c)
    temps = [make_temp(s) for s in pool]
    fixed = [t for t in current if t.kind != "temp" or t.source == ambient]
    out: list[Candidate] = []
    for src, variants in by_source.items():
        if any(t.source == src and t.kind != "temp" for t in current):
            continue  # this input already has its family in the model
        fam_terms = list(dict.fromkeys(t for c in variants for t in c.add))
        allcols = temps + [t for t in fixed if t not in temps] + fam_terms
        index = {t: i for i, t in enumerate(allcols)}
        gram = GramScorer(cache.matrix(allcols), y, groups)
        every = [index[t] for t in temps + fixed if t in index]
        best = min(variants, key=lambda c: gram.score(
            list(dict.fromkeys(every + [index[t] for t in c.add])), []).validation_rmse_um)
        Z = np.column_stack([np.ones(y.size), *(cache.column(t) for t in fixed),
                             *(cache.column(t) for t in best.add)])
        YX = np.column_stack([y, cache.matrix(temps)])
        coef, *_ = np.linalg.lstsq(Z, YX, rcond=None)
        R = YX - Z @ coef
        result = select_sensors(R[:, 1:], R[:, 0], run_ids, groups, period_s,
                                n_groups=how.n_groups, max_sensors=how.max_sensors,
                                method=how.method, seed=how.seed, scheme=scheme)
        chosen = [temps[i] for i in result.sensors]
        chosen = _within_budget(chosen, best.add, fixed, gram, index, allowed_new,
                                baseline_sources)
        if chosen is None:
            continue
        add = tuple(best.add) + tuple(t for t in chosen if t not in current)
        remove = tuple(t for t in current if t.kind == "temp" and t.source != ambient
                       and t not in chosen)
        if not remove and add == tuple(best.add):
            continue  # the selection keeps its sensors: the plain family is already a candidate
        out.append(Candidate(best.kind, add, remove, family=tuple(best.add)))
    return out


def _within_budget(chosen: list[Term], family: Sequence[Term], fixed: Sequence[Term],
                   gram: GramScorer, index: Mapping[Term, int], allowed_new: int,
                   baseline_sources: set[str]) -> list[Term] | None:
    """Drop the newcomers whose loss raises the validation RMSE least until the new sensors
    (outside the baseline's) fit ``allowed_new``; None if the family alone does not fit."""
    chosen = list(chosen)

    def new_sources(ts: Sequence[Term]) -> set[str]:
        return set(axis_sensors([*ts, *family, *fixed])) - baseline_sources

    while len(new_sources(chosen)) > allowed_new:
        newcomers = [t for t in chosen if t.source not in baseline_sources]
        if not newcomers:
            return None
        def cost(t: Term) -> float:
            keep = [index[u] for u in [*chosen, *fixed, *family] if u != t]
            return gram.score(list(dict.fromkeys(keep)), []).validation_rmse_um
        chosen.remove(min(newcomers, key=cost))
    return chosen


# ------------------------------------------------------------------ the box's limits


def state_quantisation_um(terms: Sequence[Term], coefs: Sequence[float]) -> float:
    """docs/fixed-point.md: sum over lag/rate of |c| * 0.5/alpha state units (2^-23 degC)."""
    total = 0.0
    for t, c in zip(terms, coefs, strict=True):
        if t.kind in ("lag", "rate"):
            a = round(t.params["alpha"] * (1 << ALPHA_FRAC_BITS))
            total += abs(float(c)) * 2.0 ** -23 * 0.5 * (1 << ALPHA_FRAC_BITS) / a
    return total


def fixed_point_refusal(terms: Sequence[Term], coefs: Sequence[float],
                        max_error_um: float = MAX_ERROR_UM) -> str | None:
    """Why codegen would refuse this axis (None if it fits the bound with margin)."""
    budget = STATE_SHARE * (max_error_um - FINAL_ROUNDING_UM)
    state = state_quantisation_um(terms, coefs)
    if state > budget:
        return (f"filter-state quantisation bound {state:.4g} um exceeds {budget:.4g} um "
                f"({STATE_SHARE:.0%} of the {max_error_um:g} um codegen bound less rounding)")
    if not all(math.isfinite(float(c)) for c in coefs):
        return "non-finite coefficient"
    return None


# ------------------------------------------------------------------ residual structure


def lag1_autocorrelation(residual: np.ndarray, segments: np.ndarray) -> float:
    """Pooled lag-1 autocorrelation, pairs never straddling two segments (runs or blocks)."""
    num = den = 0.0
    for g in np.unique(segments):
        r = residual[segments == g]
        if r.size < 2:
            continue
        r = r - r.mean()
        num += float(r[1:] @ r[:-1])
        den += float(r @ r)
    return num / den if den > 0 else 0.0


def noise_floor(y: np.ndarray, segments: np.ndarray) -> float:
    """Measurement-noise standard deviation from second differences (robust, MAD based).

    A smooth thermal signal has negligible second differences at these periods; white noise
    of sd s gives second differences of sd s*sqrt(6).
    """
    d2 = []
    for g in np.unique(segments):
        v = y[segments == g]
        if v.size >= 3:
            d2.append(np.diff(v, 2))
    if not d2:
        return 0.0
    d = np.concatenate(d2)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(6.0))


def residual_structure(residual: np.ndarray, y: np.ndarray, segments: np.ndarray,
                       floor: float | None = None) -> dict:
    """Is there structure left? lag-1 autocorrelation vs white noise, RMSE vs noise floor.

    ``floor``: the gauge noise if already known (from the full-rate signal: second
    differences of a thinned-out signal would count thermal curvature as noise)."""
    n = residual.size
    white = 2.0 / math.sqrt(max(n, 1))
    ac = lag1_autocorrelation(residual, segments)
    floor = noise_floor(y, segments) if floor is None else floor
    res = rmse(residual)
    above_noise = res > NOISE_MULTIPLE * floor
    structured = above_noise and ac > max(AUTOCORR_LIMIT, white)
    return {"lag1_autocorr": _round(ac, 4), "white_noise_limit": _round(white, 4),
            "residual_rmse_um": _round(res, 4), "noise_floor_um": _round(floor, 4),
            "above_noise": bool(above_noise), "structured": bool(structured)}


# ------------------------------------------------------------------ the search


@dataclass
class EffectsResult:
    """Final terms and fit, and the report that goes into model.json's axis."""

    terms: list[Term]
    coefs: np.ndarray
    intercept: float
    report: dict = field(default_factory=dict)


def _terms_json(terms: Sequence[Term], coefs: Sequence[float]) -> list[dict]:
    return [{**t.to_json(), "coef": float(c)} for t, c in zip(terms, coefs, strict=True)]


def _candidate_row(s: Scored, ref: Scored) -> dict:
    assert s.candidate is not None
    row = {"kind": s.candidate.kind, "feature": s.candidate.feature,
           "validation_rmse_um": _round(s.validation_rmse_um, 4), **s.evidence(ref),
           "passes": s.passes(ref)}
    if s.codegen:
        row["codegen_refused"] = s.codegen
    return row


def _unexplained_message(structure: dict, n_added: int, best: dict | None,
                         max_reached: bool, rule: Rule) -> str:
    head = (f"after {n_added} effect{'s' if n_added != 1 else ''} " if n_added else "")
    msg = (f"{head}the validation residual is still structured (lag-1 autocorrelation "
           f"{structure['lag1_autocorr']:.2f}, white noise would stay below "
           f"{structure['white_noise_limit']:.2f}; RMSE {structure['residual_rmse_um']:.3g} um "
           f"vs a noise floor of {structure['noise_floor_um']:.3g} um)")
    if max_reached:
        return msg + f"; the limit of {MAX_EFFECTS} effects was reached"
    if best is None:
        return msg + ", and no candidate effect applies"
    return (msg + "; no candidate effect explains it: the best, "
            f"{best['kind']} {best['feature']}, lowers the validation RMSE by "
            f"{best['improvement_pct']:.1f} % with {best['folds_improved']} folds improved "
            f"(needs >= {rule.min_gain:.0%} and every fold that exercises it better)")


def search_effects(runs: Sequence[Run], target: str, baseline: Sequence[Term], period_s: float,
                   *, ambient: str | None = None, aux: Sequence[str] | None = None,
                   max_effects: int = MAX_EFFECTS, n_blocks: int = DEFAULT_BLOCKS,
                   rule: Rule | None = None, max_error_um: float = MAX_ERROR_UM,
                   taus: Iterable[float] = TAU_GRID_S, kinds: Iterable[str] = EFFECT_KINDS,
                   selection: Mapping | None = None, max_sensors: int = DEFAULT_MAX_SENSORS,
                   max_new_sensors: int | None = None, channels_in_use: Iterable[str] = ()
                   ) -> EffectsResult:
    """Add up to ``max_effects`` validated effects to the ``baseline`` terms of one axis.

    ``ambient`` is the ambient sensor (default: a sensor named like *amb*, if any); ``aux`` the
    aux columns speed terms may use (default: every aux column of the runs). ``selection``
    (the baseline's selection trace) and ``max_sensors`` say how an input's family re-selects
    the sensors; ``max_new_sensors`` (default ``max_effects``: host.train's channel budget
    counts on at most one new sensor per effect) caps the sensors outside the baseline's and
    ``channels_in_use`` (sensors another axis already wires, which cost no channel).
    """
    runs = list(runs)
    rule = rule or Rule()
    if not runs:
        raise EffectsError("no runs")
    kinds = set(kinds)
    unknown = kinds - set(EFFECT_KINDS)
    if unknown:
        raise EffectsError(f"unknown effect kind(s) {sorted(unknown)} (known: "
                           f"{', '.join(EFFECT_KINDS)})")
    sensors = list(runs[0].sensor_names)
    aux_names = list(runs[0].aux_names if aux is None else aux)
    for name in aux_names:
        if name not in runs[0].aux_names:
            raise EffectsError(f"aux column '{name}' is not in {runs[0].path}")
    ambient = find_ambient(sensors, ambient)
    shortest = min(r.time_s[-1] - r.time_s[0] for r in runs)
    taus = tau_grid(period_s, shortest, taus)
    stride = search_stride(runs)
    groups_full, scheme = fold_groups(runs, n_blocks)
    y_full = np.concatenate([r.target(target) for r in runs])
    floor = noise_floor(y_full, groups_full)
    groups, y = every_nth(runs, stride, groups_full), every_nth(runs, stride, y_full)
    cache = FeatureCache(runs, period_s, stride)
    refs = {s: start_reference(runs, s) for s in sensors}

    run_ids = every_nth(runs, stride, np.concatenate([np.full(r.n_samples, i)
                                                      for i, r in enumerate(runs)]))
    how = Reselection.from_trace(selection, max_sensors)
    allowed_new = max_effects if max_new_sensors is None else int(max_new_sensors)
    baseline_sources = set(axis_sensors(baseline)) | set(channels_in_use)

    def fits_budget(c: Candidate) -> bool:
        return len(set(axis_sensors(c.apply(terms))) - baseline_sources) <= allowed_new

    terms = list(baseline)
    base_fit = fit_linear(cache.matrix(terms), y)
    added: list[dict] = []
    steps: list[dict] = []
    n_tested = 0
    last_best: dict | None = None
    max_reached = False
    baseline_score: Scored | None = None
    residual = np.zeros_like(y)
    while True:
        cands = [c for c in generate_candidates(terms, sensors, aux_names, ambient, period_s,
                                                taus, refs) if c.kind in kinds]
        cands += reselected_candidates(cands, cache, y, groups, run_ids, terms, sensors,
                                       ambient, period_s, scheme, how, allowed_new,
                                       baseline_sources)
        cands = [c for c in cands if fits_budget(c)]
        ref, residual, scored = score_candidates(cache, y, groups, terms, cands)
        if baseline_score is None:
            baseline_score = ref
        if len(added) >= max_effects:
            max_reached = True
            break
        if not residual_structure(residual, y, groups, floor)["above_noise"]:
            break  # the residual is at the gauge's noise: no effect to look for
        n_tested += len(scored)
        chosen: Scored | None = None
        for s in preferred([s for s in scored if s.passes(ref, rule)]):
            assert s.candidate is not None
            trial = s.candidate.apply(terms)
            fit = fit_linear(cache.matrix(trial), y)
            s.codegen = fixed_point_refusal(trial, fit.coef, max_error_um)
            if s.codegen is None:
                chosen = s
                break
        top = [_candidate_row(s, ref) for s in scored[:TOP_RECORDED]]
        refused = [_candidate_row(s, ref) for s in scored[TOP_RECORDED:] if s.codegen]
        steps.append({"validation_rmse_um": _round(ref.validation_rmse_um, 4),
                      "candidates": len(scored), "best": top + refused,
                      "added": None if chosen is None else chosen.candidate.feature})
        last_best = top[0] if top else None
        if chosen is None:
            break
        assert chosen.candidate is not None
        terms = chosen.candidate.apply(terms)
        fit = fit_linear(cache.matrix(terms), y)
        added.append({
            "kind": chosen.candidate.kind,
            "feature": chosen.candidate.feature,
            "name": chosen.candidate.feature,
            "added": [t.to_json() for t in chosen.candidate.add],
            **({"reselected": True} if chosen.candidate.family else {}),
            **({"removed": [t.to_json() for t in chosen.candidate.remove]}
               if chosen.candidate.remove else {}),
            "evidence": chosen.evidence(ref),
            "rmse_before_um": _round(ref.validation_rmse_um, 4),
            "rmse_after_um": _round(chosen.validation_rmse_um, 4),
            "intercept": float(fit.intercept),
            "terms": _terms_json(terms, fit.coef),
        })

    assert baseline_score is not None
    final = fit_linear(cache.matrix(terms), y)
    structure = residual_structure(residual, y, groups, floor)
    unexplained = None
    if structure["structured"]:
        unexplained = {k: structure[k] for k in ("lag1_autocorr", "white_noise_limit",
                                                  "residual_rmse_um", "noise_floor_um")}
        unexplained["message"] = _unexplained_message(structure, len(added), last_best,
                                                      max_reached, rule)
    report = {
        "baseline_validation_rmse_um": _round(baseline_score.validation_rmse_um, 6),
        "validation_rmse_um": _round(ref.validation_rmse_um, 6),
        "effects": added,
        "unexplained": unexplained,
        "baseline": {"intercept": float(base_fit.intercept),
                     "terms": _terms_json(baseline, base_fit.coef)},
        "effects_search": {
            "rule": (f"{rule.describe()}; searched only while the residual RMSE exceeds "
                     f"{NOISE_MULTIPLE:g}x the gauge noise; at most {max_effects} effects; the "
                     f"box's error bound must hold (<= {max_error_um:g} um)"),
            "validation": scheme,
            "kinds": [k for k in EFFECT_KINDS if k in kinds],
            "ambient": ambient,
            "aux": aux_names,
            "tau_grid_s": taus,
            "candidates_tested": n_tested,
            "residual": structure,
            "steps": steps,
        },
    }
    return EffectsResult(terms, final.coef, float(final.intercept), report)


# ------------------------------------------------------------------ sensor references


def cluster_mates(selection: Mapping | None, sensor: str) -> list[str]:
    """A sensor's redundant neighbours: the other members of its c-means group."""
    for group in (selection or {}).get("groups", []):
        if sensor in group:
            return [s for s in group if s != sensor]
    return []


MAX_MATES = 4  # mates kept per sensor, the most redundant first
MATE_POOL = 6  # cluster-mates plus the most correlated sensors, up to this many, are tried
MATE_MAX_SCATTER = 0.1  # a redundant mate predicts the sensor within 10 % of its range (RMS)


def sensor_reference(runs: Sequence[Run], sensors: Sequence[str],
                     selection: Mapping | None) -> dict:
    """How each model sensor relates to its neighbours in training (for host diagnose).

    The pool is the sensor's cluster-mates (the c-means group of the selection trace), topped
    up with the sensors most correlated with it to ``MATE_POOL``; per pool member a line
    s = a + b*m is fitted. Mates are the members whose line predicts the sensor within
    ``MATE_MAX_SCATTER`` of its range, the best ``MAX_MATES`` (if none does, the best two,
    whose scatter then makes any drift hard to prove). Also stored: the sensor's noise.
    """
    names = list(runs[0].sensor_names)
    T = np.vstack([r.temperatures for r in runs])
    seg = np.concatenate([np.full(r.n_samples, i) for i, r in enumerate(runs)])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.nan_to_num(np.corrcoef(T, rowvar=False)) if len(names) > 1 else np.ones((1, 1))
    out = {}
    for s in sensors:
        if s not in names:
            continue
        i = names.index(s)
        v = T[:, i]
        cluster = [m for m in cluster_mates(selection, s) if m in names]
        order = [names[int(j)] for j in np.argsort(-np.abs(corr[i])) if int(j) != i]
        pool = (cluster + [m for m in order if m not in cluster])[:max(MATE_POOL, len(cluster))]
        pairs = {}
        for m in pool:
            x = T[:, names.index(m)]
            fit = fit_linear(x[:, None], v)
            pairs[m] = {"intercept": float(fit.intercept), "slope": float(fit.coef[0]),
                        "rmse_c": rmse(v - fit.predict(x[:, None])),
                        "from": "cluster" if m in cluster else "correlation"}
        span = max(float(np.ptp(v)), 1e-6)
        ranked = sorted(pairs, key=lambda m: pairs[m]["rmse_c"])
        good = [m for m in ranked if pairs[m]["rmse_c"] <= MATE_MAX_SCATTER * span]
        mates = good[:MAX_MATES] if good else ranked[:2]
        out[s] = {"mates": mates, "pairs": {m: pairs[m] for m in mates},
                  "noise_c": noise_floor(v, seg),
                  "range_c": [float(v.min()), float(v.max())]}
    return out


# ------------------------------------------------------------------ the train hook


def axis_sensors(terms: Iterable[Term]) -> list[str]:
    out: list[str] = []
    for t in terms:
        if t.kind in ("temp", "lag", "rate", "square") and t.source not in out:
            out.append(str(t.source))
    return out


def add_effects(axis: dict, *, runs: Sequence[Run], target: str, period_s: float,
                n_blocks: int = DEFAULT_BLOCKS, ambient: str | None = None,
                aux: Sequence[str] | None = None, max_error_um: float = MAX_ERROR_UM,
                max_effects: int = MAX_EFFECTS, max_sensors: int = DEFAULT_MAX_SENSORS,
                max_new_sensors: int | None = None, channels_in_use: Iterable[str] = ()) -> dict:
    """host.train's effects hook: the baseline axis dict in, the final axis dict out.

    The final terms are refitted with host.train.fit_axis (same metrics as the baseline);
    the axis gains ``baseline_validation_rmse_um``, ``effects``, ``unexplained``, ``baseline``,
    ``effects_search`` and ``sensor_reference`` (used by ``host diagnose``).
    ``max_sensors``, ``max_new_sensors`` and ``channels_in_use``: see ``search_effects``.
    """
    from host.train import fit_axis  # train calls this hook: import here, not at the top

    baseline = [Term.from_json(t) for t in axis["terms"]]
    result = search_effects(runs, target, baseline, period_s, ambient=ambient, aux=aux,
                            n_blocks=n_blocks, max_error_um=max_error_um,
                            max_effects=max_effects, selection=axis.get("selection"),
                            max_sensors=max_sensors, max_new_sensors=max_new_sensors,
                            channels_in_use=channels_in_use)
    out = dict(axis)
    out.update(fit_axis(list(runs), target, result.terms, period_s, n_blocks))
    out.update(result.report)
    out["sensor_reference"] = sensor_reference(runs, axis_sensors(result.terms),
                                               axis.get("selection"))
    return out
