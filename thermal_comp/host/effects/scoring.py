"""Scoring candidates out of fold, and the rule that accepts one (material and stable).

Part of closing the loop (docs/effects.md); host.effects.search drives the steps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from thermal_comp.contract.terms import Term
from thermal_comp.host.effects.candidates import Candidate
from thermal_comp.host.effects.residual import rounded
from thermal_comp.host.fitting import (
    NO_REFERENCE,
    FoldGram,
    Reference,
    first_order_lag,
    shared_filter,
    solve_many,
    solve_normal,
    term_values,
)
from thermal_comp.host.io import Run

MIN_GAIN = 0.10  # an effect must lower the validation RMSE by at least 10 %
MIN_FOLD_GAIN = 0.0  # ... and every fold's held-out RMSE lower
ACTIVE_SHARE = 0.1  # a fold exercises an effect if its contribution varies there (SD >= 10 %)
MAX_IDLE_LOSS = 0.05  # a fold that does not exercise it may get at most 5 % worse
MAX_FOLD_SPREAD = 1.0  # the effect fitted without a fold keeps its shape (RMS change < size)
PARSIMONY = 0.01  # a candidate with fewer terms within 1 % of the best is preferred
MAX_SEARCH_ROWS = 10_000  # the search scores at most about this many samples (search_stride)


def search_stride(runs: Sequence[Run], max_rows: int = MAX_SEARCH_ROWS) -> int:
    """Every how-many-th sample the search scores, so it sees at most about ``max_rows``.

    Thermal signals change over minutes; a 24 h run at 1 s has far more rows than the
    comparison of candidates needs, and scoring ~1000 candidate columns at full rate costs
    gigabytes. Features are still computed at the full rate (filters run on every sample, as
    on the box) and the final model is refitted on every sample (by training, host.train).
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

    def __init__(self, runs: Sequence[Run], period_s: float, stride: int = 1,
                 reference: Reference = NO_REFERENCE) -> None:
        self.columns = [r.columns() for r in runs]
        self.period_s = period_s
        self.stride = stride
        self.reference = reference  # applied per run, as host.fitting.stack does
        self._cache: dict[Term, np.ndarray] = {}

    def column(self, term: Term) -> np.ndarray:
        self._fill([term])
        return self._cache[term]

    def matrix(self, terms: Sequence[Term]) -> np.ndarray:
        n = sum(len(c["time_s"][::self.stride]) for c in self.columns)
        if not terms:
            return np.empty((n, 0))
        self._fill(terms)
        return np.column_stack([self._cache[t] for t in terms])

    def gram(self, terms: Sequence[Term], y: np.ndarray, groups: np.ndarray) -> GramScorer:
        """``GramScorer(self.matrix(terms), y, groups)``, the columns copied straight into its
        design (FoldGram.of_columns): a thousand candidate columns do not sit in memory twice."""
        self._fill(terms)
        return GramScorer.of_columns([self._cache[t] for t in terms], y, groups)

    def _fill(self, terms: Sequence[Term]) -> None:
        """Compute the columns of ``terms`` not cached yet. The lags and rates of one sensor
        and time constant come from one filter pass per run (they share the filter, as on the
        box), one such group at a time, so one group's full-rate rows are held at most."""
        groups: dict[object, list[Term]] = {}
        for i, term in enumerate(dict.fromkeys(terms)):
            if term not in self._cache:
                key = shared_filter(term, self.columns[0]) if self.columns else None
                groups.setdefault(key or i, []).append(term)
        for group in groups.values():
            pieces: list[list[np.ndarray]] = [[] for _ in group]
            for cols in self.columns:
                key = shared_filter(group[0], cols) if len(group) > 1 else None
                lag = (None if key is None else
                       first_order_lag(np.asarray(cols[group[0].source], dtype=float), key[1]))
                for j, term in enumerate(group):
                    pieces[j].append(self.reference.apply(
                        term_values(term, cols, self.period_s, lag))[::self.stride])
            for term, parts in zip(group, pieces, strict=True):
                self._cache[term] = np.concatenate(parts)


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
            more = {"sensors_only_rmse_um": rounded(self.sensors_only.validation_rmse_um, 4),
                    "improvement_over_sensors_only_pct":
                        rounded(100.0 * self.gain_over(self.sensors_only), 2),
                    "folds_improved_over_sensors_only":
                        f"{self.folds_improved(self.sensors_only)}/{len(ref.fold_rmse_um)}"}
        return {
            "residual_corr": rounded(self.residual_corr, 4),
            "folds_improved": f"{self.folds_improved(ref)}/{len(ref.fold_rmse_um)}",
            "folds_exercised": f"{int(self.active().sum())}/{len(ref.fold_rmse_um)}",
            "improvement_pct": rounded(100.0 * self.gain_over(ref), 2),
            "fold_rmse_before_um": [rounded(v, 4) for v in ref.fold_rmse_um],
            "fold_rmse_after_um": [rounded(v, 4) for v in self.fold_rmse_um],
            "fold_spread": rounded(self.fold_spread, 4),
            **more,
        }


def partial_correlation(residual: np.ndarray, Z: np.ndarray, X: np.ndarray) -> float:
    """Correlation of the residual with the new columns Z once the current design X is removed.

    One column: signed Pearson r. Several: the multiple correlation R (>= 0). (A direct
    reference for ``GramScorer.partial_correlation``, which the search uses.)
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


class GramScorer(FoldGram):
    """The out-of-fold engine (host.fitting.FoldGram) asked the effect search's questions.

    Hundreds of candidates are scored at the cost of one pass over the data: each only solves
    a few small normal-equation systems. Besides the errors, a candidate's new columns must
    keep their shape without any one fold (``fold_spread``) and show where they act
    (``fold_active``); ``partial_correlation`` ranks what the residual still holds.
    """

    def score(self, cols: Sequence[int], new: Sequence[int],
              candidate: Candidate | None = None) -> Scored:
        """Out-of-fold RMSE (overall and per fold) of columns ``cols`` of X, of which ``new``
        are the candidate's: their contribution fitted without each fold is compared with
        the all-data fit (``fold_spread``, the same effect in every fold?)."""
        betas = self.fold_betas(cols)
        sse = self.fold_sse(cols, betas)
        scored = Scored(candidate, math.sqrt(sse.sum() / self.n), np.sqrt(sse / self.n_f))
        if new:
            self._effect_stability(scored, cols, new, betas)
        return scored

    def _effect_stability(self, scored: Scored, cols: Sequence[int], new: Sequence[int],
                          betas: np.ndarray, full_beta: np.ndarray | None = None) -> None:
        """Fill ``fold_spread`` and ``fold_active`` of the new columns' contribution
        (``full_beta``: ``beta(cols)``, if known)."""
        pos = np.array([list(cols).index(c) + 1 for c in new])
        nz = np.array([c + 1 for c in new])
        C = self.M[nz[:, None], nz] / self.n  # covariance of the (centred) new columns
        full = (self.beta(cols) if full_beta is None else full_beta)[pos]
        size = math.sqrt(max(float(full @ C @ full), 0.0))
        if not size > 0:
            scored.fold_spread = math.inf
            return
        spread = max(math.sqrt(max(float((b[pos] - full) @ C @ (b[pos] - full)), 0.0))
                     for b in betas)
        scored.fold_spread = spread / size
        active = []
        for Mf, nf in zip(self.M_f, self.n_f, strict=True):
            mean = float(Mf[0, nz] @ full) / nf
            var = float(full @ Mf[nz[:, None], nz] @ full) / nf - mean * mean
            active.append(math.sqrt(max(var, 0.0)) >= ACTIVE_SHARE * size)
        scored.fold_active = np.array(active)

    def partial_correlation(self, residual: np.ndarray, q: np.ndarray, base: Sequence[int],
                            new: Sequence[int], P: np.ndarray | None = None) -> float:
        """``partial_correlation`` from the Gram matrix; ``q`` = D.T @ residual (once a step);
        ``P``: the projection of the new columns on the base, if known."""
        b = self.index(base)
        z = np.array([c + 1 for c in new], dtype=int)
        G = self.M
        if P is None:
            P = solve_normal(G[b[:, None], b], G[b[:, None], z])
        zr = q[z] - P.T @ q[b]
        zz = G[z[:, None], z] - G[z[:, None], b] @ P
        rr = float(residual @ residual) - residual.size * float(residual.mean()) ** 2
        if rr <= 0:
            return 0.0
        if z.size == 1:
            den = math.sqrt(max(float(zz[0, 0]), 0.0) * rr)
            return float(zr[0]) / den if den > 0 else 0.0
        r2 = float(zr @ solve_normal(zz, zr)) / rr
        return math.sqrt(min(max(r2, 0.0), 1.0))


    def score_many(self, requests: Sequence[tuple[Sequence[int], Sequence[int],
                                                  Candidate | None]]) -> list[Scored]:
        """``[score(cols, new, candidate) for cols, new, candidate in requests]``, with the
        small normal-equation systems of all requests of one size solved in one stacked call
        (``solve_many``): LAPACK solves each matrix of a stack as it solves it alone, so every
        coefficient is the same to the last bit; only the per-call overhead goes."""
        out: list[Scored | None] = [None] * len(requests)
        by_size: dict[int, list[int]] = {}
        for k, (cols, _, _) in enumerate(requests):
            by_size.setdefault(len(cols), []).append(k)
        for size, ks in by_size.items():
            idx = np.array([self.index(requests[k][0]) for k in ks], dtype=int).reshape(
                len(ks), size + 1)
            rows, cols_ = idx[:, :, None], idx[:, None, :]
            Mg = np.moveaxis(self.M_f[:, rows, cols_], 0, 1)  # (K, F, m, m)
            vg = np.moveaxis(self.v_f[:, idx], 0, 1)  # (K, F, m)
            Ms, vs = self.M[rows, cols_], self.v[idx]  # (K, m, m), (K, m)
            betas = solve_many(Ms[:, None] - Mg, vs[:, None, :] - vg)  # K of (F, m)
            stable = [j for j, k in enumerate(ks) if requests[k][1]]
            full = solve_many(Ms[stable], vs[stable]) if stable else None
            where = {j: i for i, j in enumerate(stable)}
            for j, k in enumerate(ks):
                cols, new, cand = requests[k]
                b = betas[j]
                # fold_sse's own operands: einsum's order of summation follows their memory
                # layout, which a slice of the stack does not share
                sse = self.fold_sse(cols, b)
                scored = Scored(cand, math.sqrt(sse.sum() / self.n), np.sqrt(sse / self.n_f))
                if new:
                    self._effect_stability(scored, cols, new, b, full[where[j]])
                out[k] = scored
        return out  # type: ignore[return-value]

    def projections(self, base: Sequence[int], news: Sequence[Sequence[int]]
                    ) -> list[np.ndarray]:
        """For each of ``news``, ``partial_correlation``'s projection of those columns on the
        base columns (one stacked solve per count of new columns, see ``score_many``)."""
        b = self.index(base)
        Gbb = self.M[b[:, None], b]
        out: list[np.ndarray | None] = [None] * len(news)
        by_size: dict[int, list[int]] = {}
        for k, new in enumerate(news):
            by_size.setdefault(len(new), []).append(k)
        for ks in by_size.values():
            Z = np.array([[c + 1 for c in news[k]] for k in ks], dtype=int)
            rhs = np.moveaxis(self.M[b][:, Z], 0, 1)  # (K, base, new)
            P = solve_many(np.broadcast_to(Gbb, (len(ks), *Gbb.shape)), rhs)
            for j, k in enumerate(ks):
                out[k] = P[j]
        return out  # type: ignore[return-value]


def score_candidates(cache: FeatureCache, y: np.ndarray, groups: np.ndarray,
                     current: Sequence[Term], candidates: Sequence[Candidate]
                     ) -> tuple[Scored, np.ndarray, list[Scored]]:
    """The current model's out-of-fold score and residual, and every candidate's score,
    sorted best (lowest validation RMSE) first."""
    # every term once, in first-seen order; a dict, since `in` on a list made this quadratic
    index: dict[Term, int] = {}
    for t in [*current, *(t for cand in candidates for t in cand.add)]:
        index.setdefault(t, len(index))
    terms = list(index)
    gram = cache.gram(terms, y, groups)
    base = [index[t] for t in current]
    ref = gram.score(base, [])
    residual = gram.residual(base)
    q = gram.D.T @ residual
    requests: list[tuple[list[int], list[int], Candidate | None]] = []
    news: list[list[int]] = []
    for cand in candidates:
        cols = [index[t] for t in cand.apply(current)]
        new = [index[t] for t in cand.effect_terms]
        requests.append((cols, new, cand))
        news.append(new)
        if cand.family:
            requests.append(([c for c in cols if c not in new], [], None))
    # every candidate's systems solved in stacks (GramScorer.score_many), not one by one
    done = iter(gram.score_many(requests))
    scored = []
    for cand, new, P in zip(candidates, news, gram.projections(base, news), strict=True):
        s = next(done)
        if cand.family:
            s.sensors_only = next(done)
        s.residual_corr = gram.partial_correlation(residual, q, base, new, P)
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


def candidate_row(s: Scored, ref: Scored) -> dict:
    assert s.candidate is not None
    row = {"kind": s.candidate.kind, "feature": s.candidate.feature,
           "validation_rmse_um": rounded(s.validation_rmse_um, 4), **s.evidence(ref),
           "passes": s.passes(ref)}
    if s.codegen:
        row["codegen_refused"] = s.codegen
    return row
