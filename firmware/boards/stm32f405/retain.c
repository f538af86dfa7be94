/* Backup SRAM (BKPSRAM, 4 KiB at 0x40024000, RM0090 5.1.2): kept through a watchdog or
 * software reset, and through a power cut only with a battery on VBAT. */
#include <stdint.h>

#include "hal_retain.h"
#include "stm32f405_regs.h"

#define BKPSRAM_BASE 0x40024000u
#define BKPSRAM_SIZE 4096u

static void enable(void)
{
    static int done;
    if (!done) {
        RCC_APB1ENR |= RCC_APB1ENR_PWR;
        PWR_CR |= PWR_CR_DBP;                 /* write access to the backup domain */
        RCC_AHB1ENR |= RCC_AHB1ENR_BKPSRAM;
        PWR_CSR |= PWR_CSR_BRE;               /* backup regulator: keeps it on VBAT */
        done = 1;
    }
}

/* Whether the backup SRAM answers: its first word must read back what was written (the old
 * value is put back). A machine without it (QEMU's netduinoplus2 maps an empty 1 KiB stub
 * there and faults beyond) reports size 0: every reset is then a cold one. */
static size_t probe(void)
{
    enable();
    volatile uint32_t *w = (volatile uint32_t *)BKPSRAM_BASE;
    const uint32_t old = *w;
    *w = 0xA5C3965Au;
    const int ok = *w == 0xA5C3965Au;
    *w = old;
    return ok ? BKPSRAM_SIZE : 0u;
}

size_t hal_retain_size(void)
{
    static size_t size = 1u; /* not probed yet */
    if (size == 1u) {
        size = probe();
    }
    return size;
}

void hal_retain_read(size_t offset, void *dst, size_t n)
{
    enable();
    const volatile uint8_t *from = (const volatile uint8_t *)BKPSRAM_BASE;
    uint8_t *to = dst;
    for (size_t i = 0; i < n && offset + i < BKPSRAM_SIZE; i++) {
        to[i] = from[offset + i];
    }
}

void hal_retain_write(size_t offset, const void *src, size_t n)
{
    enable();
    volatile uint8_t *to = (volatile uint8_t *)BKPSRAM_BASE;
    const uint8_t *from = src;
    for (size_t i = 0; i < n && offset + i < BKPSRAM_SIZE; i++) {
        to[offset + i] = from[i];
    }
}
