/* Spindle speed from the drive's analogue output: 0..BOX_AUX0_RPM_FULL_SCALE rpm over
 * 0..3.3 V on PA0 (a 10 V output goes through a divider), ADC1 channel 0, 12 bits. */
#include <stdbool.h>
#include <stdint.h>

#include "board_internal.h"
#include "box_config.h"
#include "hal_aux.h"
#include "stm32f405_regs.h"

void board_adc_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_ADC1;
    board_pin_mode(GPIOA_BASE, 0, GPIO_MODE_ANALOG, 0);
    ADC_CCR = ADC_CCR_ADCPRE_DIV4;       /* 84 / 4 = 21 MHz ADC clock (max 36) */
    ADC1_SMPR2 = ADC_SMPR_480_CYCLES;    /* channel 0: long sampling, slow signal */
    ADC1_SQR1 = 0u;                      /* one conversion */
    ADC1_SQR3 = 0u;                      /* ... of channel 0 */
    ADC1_CR2 = ADC_CR2_ADON;
}

bool hal_aux_read(uint8_t index, int32_t *value)
{
    if (index != 0u) {
        return false;
    }
    ADC1_CR2 |= ADC_CR2_SWSTART;
    if (!board_wait_set(&ADC1_SR, ADC_SR_EOC, 100000u)) {
        return false;
    }
    uint32_t raw = ADC1_DR & 0xFFFu;
    *value = (int32_t)((raw * (uint32_t)BOX_AUX0_RPM_FULL_SCALE + 2047u) / 4095u);
    return true;
}
