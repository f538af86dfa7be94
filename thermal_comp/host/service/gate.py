"""The innovation gate: a reading the model's own uncertainty cannot explain is refused.

A chip on the artifact reads +50 um. The estimator predicts the reading as the model's output
plus its current estimate; the innovation (reading minus that) has variance P + R (the
estimate's variance and the probe's). A reading is refused when

    |innovation| > max(gate_sigma * sqrt(P + R), gate_floor_um)

and then changes nothing (the estimate, its variance and the output stay as they were). The
floor keeps a well-settled estimator (small P) from refusing an ordinary change; the cap on
P (``p_max_um2``) keeps the gate below a chip's size however long the box went unprobed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Gate:
    sigma: float = 4.0
    floor_um: float = 3.0

    def threshold(self, variance: float) -> float:
        """The largest |innovation| accepted when the innovation's variance is ``variance``."""
        return max(self.sigma * math.sqrt(max(variance, 0.0)), self.floor_um)

    def accepts(self, innovation: float, variance: float) -> bool:
        return abs(innovation) <= self.threshold(variance)


OPEN = Gate(math.inf, math.inf)  # accepts everything (the bench's ungated variants)
