/* Reset handler and vector table of the STM32F405 (82 peripheral interrupts, PM0214/RM0090). */
#include <stdint.h>

#include "board_internal.h"
#include "hal_board.h"
#include "stm32f405_regs.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;

void Reset_Handler(void);
void Default_Handler(void);

void Reset_Handler(void)
{
    /* .data from flash, .bss zeroed: word loops, no library call before RAM is ready. */
    const uint32_t *src = &_sidata;
    for (uint32_t *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0u;
    }
    (void)app_main();
    for (;;) {
        /* app_main never returns on the box; if it did, the watchdog restarts it. */
    }
}

/* Any unexpected exception (HardFault from a stack overflow into the guard below RAM, a bus
 * fault, a stray interrupt): stop here and let the independent watchdog reset the chip, so the
 * next boot reports WDT_RESET. */
void Default_Handler(void)
{
    for (;;) {
    }
}

#define WEAK_DEFAULT __attribute__((weak, alias("Default_Handler")))
void NMI_Handler(void) WEAK_DEFAULT;
void HardFault_Handler(void) WEAK_DEFAULT;
void MemManage_Handler(void) WEAK_DEFAULT;
void BusFault_Handler(void) WEAK_DEFAULT;
void UsageFault_Handler(void) WEAK_DEFAULT;
void SVC_Handler(void) WEAK_DEFAULT;
void DebugMon_Handler(void) WEAK_DEFAULT;
void PendSV_Handler(void) WEAK_DEFAULT;

#define N_IRQ 82u
typedef void (*vector_t)(void);

__attribute__((section(".isr_vector"), used)) static const vector_t vectors[16u + N_IRQ] = {
    [0] = (vector_t)(uintptr_t)&_estack,
    [1] = Reset_Handler,
    [2] = NMI_Handler,
    [3] = HardFault_Handler,
    [4] = MemManage_Handler,
    [5] = BusFault_Handler,
    [6] = UsageFault_Handler,
    [7 ... 10] = 0,
    [11] = SVC_Handler,
    [12] = DebugMon_Handler,
    [13] = 0,
    [14] = PendSV_Handler,
    [15] = SysTick_Handler,
    [16 ... 16u + USART1_IRQN - 1u] = Default_Handler,
    [16u + USART1_IRQN] = USART1_IRQHandler,
    [16u + USART1_IRQN + 1u ... 16u + N_IRQ - 1u] = Default_Handler,
};
