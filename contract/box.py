"""Capacities of the box and of its model runtime: what a model may ask of the hardware.

Two different limits, often confused: the box has ``BOX_CHANNELS`` thermocouple inputs (one
MAX31856 chip select each, ``BOX_MAX_CHANNELS`` in firmware/include/box_config.h), while the
model runtime's tables could describe up to ``RUNTIME_MAX_CHANNELS`` (``TCM_MAX_CHANNELS`` in
firmware/include/model_eval.h, a uint32_t mask). Training and codegen refuse a model that
needs more than the box has. tests/test_contract.py checks both headers against this file.
"""

from __future__ import annotations

BOX_CHANNELS = 8  # MAX31856 chip selects on the box (PC0..PC7)
BOX_AXES = 6  # axes the application keeps output state for (BOX_MAX_AXES)
BOX_AUX = 2  # auxiliary inputs (BOX_MAX_AUX)
BOX_STATES = 32  # filter states the box has room for over all axes
RUNTIME_MAX_CHANNELS = 32
RUNTIME_MAX_AUX = 8
RUNTIME_MAX_AXES = 32
RUNTIME_MAX_STATES = 32
RUNTIME_MAX_TERMS_PER_AXIS = 255
RUNTIME_FORMAT = 2  # TCM_RUNTIME_FORMAT: channels carry the training window (EXTRAP)
HEADER_FORMAT = RUNTIME_FORMAT
CHANNEL_MIN_C = -40.0  # default valid range of a thermocouple channel
CHANNEL_MAX_C = 200.0
