"""Capacities of the box and of its model runtime: what a model may ask of the hardware.

Two different limits, often confused: the box has ``BOX_CHANNELS`` thermocouple inputs (one
MAX31856 chip select each, ``BOX_MAX_CHANNELS`` in firmware/include/box_config.h), while the
model runtime's tables could describe up to ``RUNTIME_MAX_CHANNELS`` (``TCM_MAX_CHANNELS`` in
firmware/include/model_eval.h, a uint32_t mask). Training and codegen refuse a model that
needs more than the box has. tests/contract/test_contract.py checks both headers against this file.
"""

from __future__ import annotations

BOX_CHANNELS = 8  # MAX31856 chip selects on the box (PC0..PC7)
BOX_AXES = 6  # axes the application keeps output state for (BOX_MAX_AXES)
BOX_AUX = 2  # auxiliary inputs (BOX_MAX_AUX)
BOX_STATES = 32  # distinct filters (sensor, time constant) the box has room for, all axes
RUNTIME_MAX_CHANNELS = 32
RUNTIME_MAX_AUX = 8
RUNTIME_MAX_AXES = 32
RUNTIME_MAX_STATES = 32
RUNTIME_MAX_TERMS_PER_AXIS = 255
# TCM_RUNTIME_FORMAT: 2 channels carry the training window (EXTRAP); 3 channels carry their
# largest plausible step (IMPLAUSIBLE) and axes their output step limit, both CRC-covered; 4 a
# lag/rate term names its filter state, shared by the terms of one channel and time constant; 5
# channels carry their stuck limit (max_still_samples, STUCK), CRC-covered; 6 axes carry the
# in-service estimator's parameters (issue 42, MEAS), CRC-covered; 7 and its re-opening count
# (reopen_after, the gate's lock-out), CRC-covered
RUNTIME_FORMAT = 7
HEADER_FORMAT = RUNTIME_FORMAT
ZERO_SAMPLES = 8  # a ZERO's reference is the mean of this many samples (BOX_ZERO_SAMPLES)
CHANNEL_MIN_C = -40.0  # default valid range of a thermocouple channel
CHANNEL_MAX_C = 200.0

# ---- Step limits: how fast a channel and an axis output may physically change ----
# host train derives them from the training runs (host/train/ranges.py) and stores them in
# model.json (channels[i].max_step_c, axes[a].max_step_um); codegen writes them into the header
# (max_step_code per channel, max_step_nm per axis) where the box applies them.
STEP_MARGIN = 4  # limit = margin x the fastest change per sample seen in training
CHANNEL_STEP_FLOOR_C = 8 / 128  # at least 8 codes (1/16 degC): sensor noise is never flagged
AXIS_STEP_FLOOR_UM = 0.5  # at least 0.5 um per sample: a nearly static model is not frozen
# A stuck channel (a frozen converter repeats one code forever): host train stores per channel
# channels[i].max_still_samples = max(STILL_MARGIN x the longest run of identical codes in any
# training run, STILL_FLOOR), at most MAX_STILL_SAMPLES; the box faults a channel whose code
# stayed the same for that many samples in a row (STUCK). Absent: no stuck check.
STILL_MARGIN = 2
STILL_FLOOR = 10  # samples: live thermocouples change code almost every sample (3-8 in a row)
MAX_STILL_SAMPLES = 65535  # uint16_t in the header
MIN_STILL_SAMPLES = 2  # 1 would fault every reading
# A model.json from before the limits (no max_step_c / max_step_um): codegen's documented
# conservative defaults per sample period of period_s seconds.
DEFAULT_CHANNEL_STEP_C_PER_S = 0.1  # a structure thermocouple moves far slower
DEFAULT_CHANNEL_STEP_MIN_C = 1.0
DEFAULT_AXIS_STEP_UM_PER_S = 1.0  # the box's walk-back rate (BOX_SLEW_NM_PER_S default)
