/* Build-time configuration of the box. Override any of these with -D on the make command line,
 * e.g. `make BOARD=stm32f405 MODEL=... BOX_CFLAGS='-DBOX_SLEW_NM_PER_S=500'`.
 * docs/firmware.md explains what each one does and why the defaults are what they are. */
#ifndef BOX_CONFIG_H
#define BOX_CONFIG_H

#define BOX_FW_VERSION_DEFAULT "0.1.0"
#ifndef BOX_FW_VERSION
#define BOX_FW_VERSION BOX_FW_VERSION_DEFAULT
#endif

/* Largest number of MAX31856 chips (one chip select each). */
#ifndef BOX_MAX_CHANNELS
#define BOX_MAX_CHANNELS 8
#endif

/* Largest number of axes and auxiliary inputs the application keeps state for. */
#ifndef BOX_MAX_AXES
#define BOX_MAX_AXES 6
#endif
#ifndef BOX_MAX_AUX
#define BOX_MAX_AUX 2
#endif

/* Walk-back rate after a hold (and from 0 after power-up), nanometres per second. */
#ifndef BOX_SLEW_NM_PER_S
#define BOX_SLEW_NM_PER_S 1000
#endif

/* Every correction is clamped to +-this many nanometres (CLAMP status bit). */
#ifndef BOX_MAX_CORRECTION_NM
#define BOX_MAX_CORRECTION_NM 200000
#endif

/* 1: after power-up the output starts at 0 and walks to the first computed value at the slew
 * limit (a box power-cycled mid-job never steps an axis). 0: the first valid value is output
 * directly. */
#ifndef BOX_COLD_START_SLEW
#define BOX_COLD_START_SLEW 1
#endif

/* Plausibility guard: a channel whose reading changes by more than its model limit
 * (TCM channel max_step_code per sample) this many samples in a row becomes a fault (HOLD);
 * fewer implausible readings are replaced by the channel's last good value (IMPLAUSIBLE). */
#ifndef BOX_IMPLAUSIBLE_FAULT_SAMPLES
#define BOX_IMPLAUSIBLE_FAULT_SAMPLES 3
#endif

/* Extrapolation bound: a valid reading beyond its channel's training window (the training
 * range +- 5 %, EXTRAP) by more than this share of the window's span, and at least
 * BOX_BEYOND_MIN_CODES (1/128 degC), is beyond what training supports: the channel is a fault
 * (BEYOND) and the axes that read it hold. docs/firmware.md has the measurement behind it. */
#ifndef BOX_BEYOND_SPAN_PERCENT
#define BOX_BEYOND_SPAN_PERCENT 50
#endif
#ifndef BOX_BEYOND_MIN_CODES
#define BOX_BEYOND_MIN_CODES 640
#endif

/* ZERO: the reference of each axis is the mean model correction of this many samples (valid
 * for that axis) starting with the first sample after the command. */
#ifndef BOX_ZERO_SAMPLES
#define BOX_ZERO_SAMPLES 8
#endif

/* MEAS (issue 42): how many of the latest samples the box remembers per axis for a probe
 * reading that names its sample (docs/service.md, "On the box"). 4 covers a reading that
 * arrives up to 3 sample periods after the sample it names (3 min at the trained 60 s
 * period); a probing cycle sends it within seconds. Each costs 5 B per axis of RAM. */
#ifndef BOX_MEAS_SAMPLES
#define BOX_MEAS_SAMPLES 4
#endif

/* Independent-watchdog timeout: the main loop passes at least once per millisecond tick. */
#ifndef BOX_WATCHDOG_MS
#define BOX_WATCHDOG_MS 500
#endif

/* MAX31856 conversion settings: mains filter 50 Hz (1) or 60 Hz (0); averaged samples per
 * conversion as the CR1 AVGSEL code (0=1, 1=2, 2=4, 3=8, 4=16 samples). */
#ifndef BOX_MAINS_50HZ
#define BOX_MAINS_50HZ 1
#endif
#ifndef BOX_TC_AVGSEL
#define BOX_TC_AVGSEL 2
#endif

/* Spindle-speed input: rpm at full scale of the analogue input (box: 3.3 V on PA0). */
#ifndef BOX_AUX0_RPM_FULL_SCALE
#define BOX_AUX0_RPM_FULL_SCALE 12000
#endif

_Static_assert(BOX_AUX0_RPM_FULL_SCALE > 0 && BOX_AUX0_RPM_FULL_SCALE <= 1000000, "aux scale");
_Static_assert(BOX_MAX_CHANNELS >= 1 && BOX_MAX_CHANNELS <= 16, "1..16 chip selects");
_Static_assert(BOX_SLEW_NM_PER_S > 0 && BOX_SLEW_NM_PER_S <= 4194304,
               "slew limit must be positive and at most 2^22 nm/s");
_Static_assert(BOX_MAX_CORRECTION_NM > 0 && BOX_MAX_CORRECTION_NM < 2000000000,
               "clamp must be positive and fit int32");
_Static_assert(BOX_WATCHDOG_MS >= 10 && BOX_WATCHDOG_MS <= 4000, "IWDG range at 1 kHz");
_Static_assert(BOX_IMPLAUSIBLE_FAULT_SAMPLES >= 1 && BOX_IMPLAUSIBLE_FAULT_SAMPLES <= 255,
               "implausible readings before a fault: 1..255");
_Static_assert(BOX_ZERO_SAMPLES >= 1 && BOX_ZERO_SAMPLES <= 3600, "ZERO reference samples: 1..3600");
_Static_assert(BOX_BEYOND_SPAN_PERCENT >= 0 && BOX_BEYOND_SPAN_PERCENT <= 100000, "beyond margin");
_Static_assert(BOX_BEYOND_MIN_CODES >= 0 && BOX_BEYOND_MIN_CODES <= 524288, "beyond margin");
_Static_assert(BOX_TC_AVGSEL >= 0 && BOX_TC_AVGSEL <= 4, "AVGSEL code 0..4");

#endif
