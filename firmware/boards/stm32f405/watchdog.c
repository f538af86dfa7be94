/* Independent watchdog (IWDG, LSI ~32 kHz) and the reset cause it leaves in RCC_CSR. */
#include <stdbool.h>
#include <stdint.h>

#include "board_internal.h"
#include "hal_watchdog.h"
#include "stm32f405_regs.h"

static bool reset_by_watchdog;
static bool reset_warm;

void board_watchdog_read_reset_cause(void)
{
    uint32_t csr = RCC_CSR;
    reset_by_watchdog = (csr & RCC_CSR_IWDGRSTF) != 0u;
    /* RM0090 6.3.21: BORRSTF is also set by a power-on reset, PORRSTF only by that. */
    reset_warm = reset_by_watchdog || (csr & RCC_CSR_SFTRSTF) != 0u ||
                 ((csr & RCC_CSR_BORRSTF) != 0u && (csr & RCC_CSR_PORRSTF) == 0u);
    RCC_CSR |= RCC_CSR_RMVF; /* clear, so the next reset reports its own cause */
}

bool hal_reset_was_watchdog(void)
{
    return reset_by_watchdog;
}

bool hal_reset_was_warm(void)
{
    return reset_warm;
}

void hal_watchdog_start(uint32_t timeout_ms)
{
    if (timeout_ms > 4095u) {
        timeout_ms = 4095u;
    }
    DBGMCU_APB1_FZ |= DBGMCU_APB1_FZ_IWDG_STOP; /* a debugger halt is not a stuck loop */
    IWDG_KR = IWDG_KEY_START;                    /* also starts the LSI */
    IWDG_KR = IWDG_KEY_UNLOCK;
    IWDG_PR = IWDG_PR_DIV32; /* 1 count per ms */
    IWDG_RLR = timeout_ms;
    for (uint32_t tries = 100000u; IWDG_SR != 0u && tries > 0u; tries--) {
    }
    IWDG_KR = IWDG_KEY_RELOAD;
}

void hal_watchdog_kick(void)
{
    IWDG_KR = IWDG_KEY_RELOAD;
}
