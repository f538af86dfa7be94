"""The box's build-time configuration as the host's twin needs it (firmware box_config.h).

The twin must be built like the firmware: the defaults come from the checkout's box_config.h,
overridden by any ``-D`` the build passed, so a changed default cannot drift from the twin.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thermal_comp.contract.errors import InputError
from thermal_comp.hil.build import firmware_dir


@dataclass(frozen=True)
class OutputConfig:
    """The output stage's build-time configuration (box_config.h)."""

    slew_nm_per_s: int
    max_abs_nm: int
    cold_start_slew: bool
    max_channels: int = 8
    max_axes: int = 6
    max_aux: int = 2
    implausible_after: int = 3  # BOX_IMPLAUSIBLE_FAULT_SAMPLES
    zero_samples: int = 8  # BOX_ZERO_SAMPLES
    beyond_span_percent: int = 50  # BOX_BEYOND_SPAN_PERCENT
    beyond_min_codes: int = 640  # BOX_BEYOND_MIN_CODES
    meas_samples: int = 4  # BOX_MEAS_SAMPLES: samples the box remembers for MEAS

    def beyond_limits(self, wlo: np.ndarray, whi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per channel, the codes beyond which a reading is BEYOND (box_config.h)."""
        margin = np.maximum((whi - wlo) * self.beyond_span_percent // 100, self.beyond_min_codes)
        return wlo - margin, whi + margin

    def step_nm(self, period_ms: int) -> int:
        """Slew step per sample period, as axis_output_step_nm: rounded, at least 1 nm."""
        return max(1, min((self.slew_nm_per_s * period_ms + 500) // 1000, 2**31 - 1))

    @classmethod
    def from_build(cls, cflags: str = "", config_h: Path | None = None) -> OutputConfig:
        """Defaults from box_config.h (the checkout's, unless given), overridden by
        ``-DNAME=value`` in the build's cflags."""
        config_h = config_h or firmware_dir() / "include" / "box_config.h"
        text = config_h.read_text(encoding="utf-8")
        values: dict[str, int] = {}
        for name in ("BOX_SLEW_NM_PER_S", "BOX_MAX_CORRECTION_NM", "BOX_COLD_START_SLEW",
                     "BOX_MAX_CHANNELS", "BOX_MAX_AXES", "BOX_MAX_AUX",
                     "BOX_IMPLAUSIBLE_FAULT_SAMPLES", "BOX_ZERO_SAMPLES",
                     "BOX_BEYOND_SPAN_PERCENT", "BOX_BEYOND_MIN_CODES", "BOX_MEAS_SAMPLES"):
            m = re.search(rf"^#define {name} (\d+)\s*$", text, re.M)
            if m is None:
                raise InputError(f"{config_h}: no '#define {name} <number>' default")
            values[name] = int(m.group(1))
        for m in re.finditer(r"-D(BOX_\w+)=(\d+)", cflags):
            if m.group(1) in values:
                values[m.group(1)] = int(m.group(2))
        return cls(values["BOX_SLEW_NM_PER_S"], values["BOX_MAX_CORRECTION_NM"],
                   bool(values["BOX_COLD_START_SLEW"]), values["BOX_MAX_CHANNELS"],
                   values["BOX_MAX_AXES"], values["BOX_MAX_AUX"],
                   values["BOX_IMPLAUSIBLE_FAULT_SAMPLES"], values["BOX_ZERO_SAMPLES"],
                   values["BOX_BEYOND_SPAN_PERCENT"], values["BOX_BEYOND_MIN_CODES"],
                   values["BOX_MEAS_SAMPLES"])

    def check_fits(self, n_channels: int, n_axes: int, n_aux: int, what: str) -> None:
        """The firmware refuses (MODEL_BAD) a model larger than its build-time capacity."""
        for count, limit, name in ((n_channels, self.max_channels, "channels"),
                                   (n_axes, self.max_axes, "axes"), (n_aux, self.max_aux, "aux")):
            if count > limit:
                raise InputError(f"{what}: {count} {name}, the firmware is built for at most "
                                 f"{limit} (BOX_MAX_{name.upper()} in firmware/include/"
                                 f"box_config.h); the box would report MODEL_BAD")
