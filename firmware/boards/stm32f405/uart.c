/* USART1, 115200 8N1. Receive is interrupt driven into a ring buffer, so no command byte is lost
 * while the main loop is busy. Transmit polls TXE: a full sample line takes ~12 ms of a 1 s
 * period, and polling works identically on the chip and in QEMU (whose USART model raises no
 * TXE interrupt). */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_internal.h"
#include "hal_uart.h"
#include "stm32f405_regs.h"

#define UART_BAUD 115200u
#define TX_BYTE_TRIES 200000u /* one byte takes 87 us = ~15000 core cycles */
#define RX_SIZE 128u /* two full commands */

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint16_t rx_head, rx_tail; /* head: written by the ISR, tail: by main */

void board_uart_init(void)
{
    RCC_APB2ENR |= RCC_APB2ENR_USART1;
    board_pin_mode(GPIOA_BASE, 9, GPIO_MODE_AF, 7);
    board_pin_mode(GPIOA_BASE, 10, GPIO_MODE_AF, 7);
    /* Oversampling by 16: BRR = fPCLK2 / baud (mantissa.fraction in 12.4). */
    USART1_BRR = (APB2_CLOCK_HZ + UART_BAUD / 2u) / UART_BAUD;
    USART1_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    NVIC_ISER(USART1_IRQN / 32u) = 1u << (USART1_IRQN % 32u);
}

void USART1_IRQHandler(void)
{
    uint32_t sr = USART1_SR;
    if (sr & (USART_SR_RXNE | USART_SR_ORE)) {
        uint8_t b = (uint8_t)USART1_DR; /* reading DR also clears an overrun */
        uint16_t next = (uint16_t)((rx_head + 1u) % RX_SIZE);
        if (next != rx_tail) { /* full: drop; the command parser sees a broken line */
            rx_buf[rx_head] = b;
            rx_head = next;
        }
    }
}

void hal_uart_write(const uint8_t *data, size_t len)
{
    for (size_t i = 0; i < len; i++) {
        /* A transmitter that never empties (broken clock) must not hang the loop for good:
         * the byte is dropped, the line's CRC then tells the receiver. */
        (void)board_wait_set(&USART1_SR, USART_SR_TXE, TX_BYTE_TRIES);
        USART1_DR = data[i];
    }
}

bool board_uart_rx_pending(void)
{
    return rx_tail != rx_head;
}

size_t hal_uart_read(uint8_t *buf, size_t max)
{
    size_t n = 0;
    while (n < max && rx_tail != rx_head) {
        buf[n++] = rx_buf[rx_tail];
        rx_tail = (uint16_t)((rx_tail + 1u) % RX_SIZE);
    }
    return n;
}
