"""The box's free thermocouple channels: which of the other sensors the ridge reads.

The axes' selections leave channels of the box unused; each axis's L1 ranking of the pool
(host.selection.screening) takes its turn at them until the budget is wired.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from thermal_comp.host.fitting import Reference
from thermal_comp.host.io import Run
from thermal_comp.host.selection import fill_free_channels, l1_ranking
from thermal_comp.host.train.ridge_family import lag_taus


def fill_rankings(runs: Sequence[Run], targets: Sequence[str], pool: Sequence[str], *,
                  period_s: float, n_blocks: int, reference: Reference) -> list[list[str]]:
    """Each axis's L1 ranking of ``pool`` (host.selection.screening): the order its turns
    at the free channels go in. It does not depend on what is wired already."""
    taus = lag_taus(runs, period_s)
    return [l1_ranking(runs, t, pool, period_s=period_s, taus=taus, n_blocks=n_blocks,
                       reference=reference) for t in targets]


def channel_fill(runs: Sequence[Run], targets: Sequence[str], wired: Sequence[str],
                 pool: Sequence[str], *, max_channels: int, period_s: float, n_blocks: int,
                 reference: Reference,
                 rankings: Callable[[], list[list[str]]] | None = None) -> list[str]:
    """The sensors of ``pool`` the ridge reads on the free channels: each axis's L1 ranking
    in turn until ``max_channels`` are wired. ``rankings`` gives fill_rankings of these
    runs, targets and pool when the caller has them already (computed only if needed)."""
    if len(wired) >= max_channels:
        return []
    ranked = rankings() if rankings is not None else fill_rankings(
        runs, targets, pool, period_s=period_s, n_blocks=n_blocks, reference=reference)
    return fill_free_channels(wired, ranked, max_channels)
