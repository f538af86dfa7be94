/* The status word of docs/protocol.md (sample and STATUS lines), and per-channel fault bits. */
#ifndef STATUS_H
#define STATUS_H

#include <stdint.h>

#define STATUS_MODEL_BAD ((uint16_t)1u << 0)
#define STATUS_HOLD ((uint16_t)1u << 1)
#define STATUS_SLEW ((uint16_t)1u << 2)
#define STATUS_CLAMP ((uint16_t)1u << 3)
#define STATUS_RANGE ((uint16_t)1u << 4)
#define STATUS_OPEN ((uint16_t)1u << 5)
#define STATUS_TC_FAULT ((uint16_t)1u << 6)
#define STATUS_AUX_FAULT ((uint16_t)1u << 7)
#define STATUS_WDT_RESET ((uint16_t)1u << 8)
#define STATUS_NO_DATA ((uint16_t)1u << 9)
#define STATUS_EXTRAP ((uint16_t)1u << 10) /* a valid reading beyond its training window */
#define STATUS_REFERENCED ((uint16_t)1u << 11) /* a ZERO reference is in force */
#define STATUS_IMPLAUSIBLE ((uint16_t)1u << 12) /* a reading changed faster than physics allows */
#define STATUS_NO_REF ((uint16_t)1u << 13) /* start-referenced model, cold power-up: hold until ZERO */
#define STATUS_BEYOND ((uint16_t)1u << 14) /* a reading beyond what training supports: axes hold */

/* Per-channel fault word reported by STATUS: bits 0-7 are the MAX31856 fault status register
 * as last read, then the box's own findings. */
#define CHFAULT_SR_MASK ((uint16_t)0x00FFu)
#define CHFAULT_RANGE ((uint16_t)1u << 8)       /* code outside the channel's valid range */
#define CHFAULT_NO_RESPONSE ((uint16_t)1u << 9) /* bus error or configuration not read back */
#define CHFAULT_IMPLAUSIBLE ((uint16_t)1u << 10) /* reading rejected by the plausibility guard */
#define CHFAULT_BEYOND ((uint16_t)1u << 11)      /* beyond the trained range plus its margin */
#define CHFAULT_STUCK ((uint16_t)1u << 12)       /* one code max_still_samples times in a row */

#endif
