/* Memory that survives a warm reset (watchdog, brown-out with the backup domain powered, a
 * software reset) but not a power cut without a backup battery: the STM32F405's 4 KiB backup
 * SRAM (BKPSRAM). The application keeps its state there every sample and resumes from it
 * after a warm reset (docs/firmware.md, "Never worse than no compensation"). */
#ifndef HAL_RETAIN_H
#define HAL_RETAIN_H

#include <stddef.h>

/* Bytes of retained memory; 0 when the board has none (the box then always boots cold). */
size_t hal_retain_size(void);

/* Copy n bytes of the retained memory from byte `offset` on out, or into it (offset + n <=
 * hal_retain_size(); bytes beyond are neither read nor written: the box writes its whole
 * block after each sample, a state block the controller uploads (LOAD) arrives in pieces,
 * and a marker word sits after the block). Its content after a power cut is arbitrary: the
 * caller checks it (magic, CRC). */
void hal_retain_read(size_t offset, void *dst, size_t n);
void hal_retain_write(size_t offset, const void *src, size_t n);

#endif
