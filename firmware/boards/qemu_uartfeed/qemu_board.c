/* Board variant `qemu_uartfeed`: the STM32F405 image under `qemu-system-arm -M netduinoplus2`
 * (docs/hil.md). QEMU's SPI1 has nothing attached, so the lowest HAL takes the samples from a
 * second UART instead: USART2 carries the native board's feed (`S <aux0> <code0> ...`,
 * `F <ch> <sr_hex>`), each S loads the simulated MAX31856 chips (emul/max31856_sim.c,
 * register level, so the real driver still talks SPI to them) and advances a virtual clock by
 * one sample period, exactly like the native board. USART1 (the protocol), the startup code,
 * the watchdog and everything above the HAL are the STM32F405 board's and the application's
 * own files.
 *
 * USART2 receives by interrupt into a ring buffer and the loop sleeps in WFI between bytes:
 * busy-polling the USART's status register keeps QEMU's I/O thread from delivering the next
 * byte (about 4,600 bytes/s polled). The STM32F405 vector table (boards/stm32f405/startup.c) has
 * no USART2 entry, so this board copies it to RAM with one added and points VTOR there. QEMU's
 * USART holds one received byte at a time and offers the next only after DR is read, so
 * nothing is lost while the ring has room; the ring is larger than one window of feed lines
 * would need only if the host floods it, so the host keeps a bounded window in flight. */
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "board_internal.h"
#include "box_config.h"
#include "hal_aux.h"
#include "hal_board.h"
#include "hal_retain.h"
#include "hal_spi.h"
#include "hal_time.h"
#include "hal_watchdog.h"
#include "max31856_sim.h"
#include "stm32f405_regs.h"

#define USART2_BASE 0x40004400u
#define USART2_SR REG32(USART2_BASE + 0x00u)
#define USART2_DR REG32(USART2_BASE + 0x04u)
#define USART2_BRR REG32(USART2_BASE + 0x08u)
#define USART2_CR1 REG32(USART2_BASE + 0x0Cu)
#define RCC_APB1ENR_USART2 (1u << 17)
#define APB1_CLOCK_HZ 42000000u
#define USART2_IRQN 38u
#define N_VECTORS (16u + 82u)

typedef void (*vector_t)(void);
void USART2_IRQHandler(void);

/* "S" + aux + BOX_MAX_CHANNELS codes of at most 8 characters each, with margin. */
#define FEED_LINE_MAX (16u + 12u + 9u * BOX_MAX_CHANNELS)

static max31856_sim_t chips[BOX_MAX_CHANNELS];
static int chip_count = -1; /* fixed by the first S line */
static int32_t aux0;
static uint32_t now_ms;
static char feed_line[FEED_LINE_MAX];
/* 512-byte alignment: VTOR needs the table aligned to its size rounded up to a power of 2. */
static vector_t ram_vectors[N_VECTORS] __attribute__((aligned(512)));
#define FEED_RING 1024u
static volatile uint8_t ring[FEED_RING];
static volatile uint32_t ring_head, ring_tail; /* head: ISR, tail: main loop */
static uint32_t feed_len;
static bool feed_overlong;

/* ---- helpers the STM32F405 board files (uart.c) call; same as boards/stm32f405/board.c ------- */

bool board_wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t tries)
{
    while (tries-- > 0u) {
        if ((*reg & mask) == mask) {
            return true;
        }
    }
    return false;
}

void board_pin_mode(uint32_t gpio_base, unsigned pin, uint32_t mode, uint32_t af)
{
    GPIO_MODER(gpio_base) = (GPIO_MODER(gpio_base) & ~(3u << (2u * pin))) | (mode << (2u * pin));
    if (mode == GPIO_MODE_AF) {
        volatile uint32_t *afr = pin < 8u ? &GPIO_AFRL(gpio_base) : &GPIO_AFRH(gpio_base);
        unsigned shift = 4u * (pin % 8u);
        *afr = (*afr & ~(0xFu << shift)) | (af << shift);
    }
}

/* ---- board, time ------------------------------------------------------------------------- */

void hal_board_init(void)
{
    board_watchdog_read_reset_cause();
    RCC_AHB1ENR |= RCC_AHB1ENR_GPIOA;
    RCC_APB1ENR |= RCC_APB1ENR_USART2;
    board_uart_init(); /* USART1: the protocol, as on the box */
    /* USART2 (PA2/PA3, AF7): the sample feed. QEMU receives only with UE, TE and RE set. */
    board_pin_mode(GPIOA_BASE, 2, GPIO_MODE_AF, 7);
    board_pin_mode(GPIOA_BASE, 3, GPIO_MODE_AF, 7);
    USART2_BRR = (APB1_CLOCK_HZ + 115200u / 2u) / 115200u;
    const vector_t *flash_vectors = (const vector_t *)(uintptr_t)SCB_VTOR;
    for (unsigned i = 0; i < N_VECTORS; i++) {
        ram_vectors[i] = flash_vectors[i];
    }
    ram_vectors[16u + USART2_IRQN] = USART2_IRQHandler;
    SCB_VTOR = (uint32_t)(uintptr_t)ram_vectors;
    USART2_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE | USART_CR1_RXNEIE;
    NVIC_ISER(USART2_IRQN / 32u) = 1u << (USART2_IRQN % 32u);
    for (unsigned i = 0; i < BOX_MAX_CHANNELS; i++) {
        max31856_sim_reset(&chips[i]);
    }
}

/* Time is virtual (advanced by the feed), so SysTick stays off; the vector table still
 * names a handler. */
void SysTick_Handler(void)
{
}

uint32_t hal_millis(void)
{
    return now_ms;
}

/* ---- the simulated chips behind SPI, the aux input from the feed ------------------------ */

bool hal_spi_transfer(uint8_t cs, const uint8_t *tx, uint8_t *rx, size_t len)
{
    if (cs >= BOX_MAX_CHANNELS) {
        return false;
    }
    max31856_sim_transfer(&chips[cs], tx, rx, len);
    return true;
}

bool hal_aux_read(uint8_t index, int32_t *value)
{
    if (index != 0u) {
        return false; /* the feed carries one aux input */
    }
    *value = aux0;
    return true;
}

/* ---- feed parsing (no libc: the image links none of it) ---------------------------------- */

static const char *skip_blanks(const char *p)
{
    while (*p == ' ' || *p == '\t' || *p == '\r') {
        p++;
    }
    return p;
}

/* One signed integer token in `base` (10 or 16) within [lo, hi]; advances *p past it. */
static bool parse_int(const char **p, unsigned base, int64_t lo, int64_t hi, int32_t *out)
{
    const char *s = skip_blanks(*p);
    bool neg = false;
    if (*s == '-' && base == 10u) {
        neg = true;
        s++;
    }
    int64_t v = 0;
    unsigned digits = 0;
    for (;; s++, digits++) {
        unsigned d;
        if (*s >= '0' && *s <= '9') {
            d = (unsigned)(*s - '0');
        } else if (base == 16u && *s >= 'a' && *s <= 'f') {
            d = (unsigned)(*s - 'a') + 10u;
        } else if (base == 16u && *s >= 'A' && *s <= 'F') {
            d = (unsigned)(*s - 'A') + 10u;
        } else {
            break;
        }
        if (digits >= 10u) {
            return false;
        }
        v = v * (int64_t)base + (int64_t)d;
    }
    if (digits == 0u || (*s != '\0' && *s != ' ' && *s != '\t' && *s != '\r')) {
        return false;
    }
    v = neg ? -v : v;
    if (v < lo || v > hi) {
        return false;
    }
    *out = (int32_t)v;
    *p = s;
    return true;
}

/* A sample: load the chips and the aux input. False if the line is malformed (ignored). */
static bool feed_sample(const char *p)
{
    int32_t aux, codes[BOX_MAX_CHANNELS];
    int n = 0;
    if (!parse_int(&p, 10u, INT32_MIN, INT32_MAX, &aux)) {
        return false;
    }
    while (*skip_blanks(p) != '\0') {
        if (n >= (int)BOX_MAX_CHANNELS ||
            !parse_int(&p, 10u, MAX31856_SIM_CODE_MIN, MAX31856_SIM_CODE_MAX, &codes[n])) {
            return false;
        }
        n++;
    }
    if (n == 0 || (chip_count >= 0 && n != chip_count)) {
        return false;
    }
    if (chip_count < 0) {
        chip_count = n;
        for (int i = 0; i < (int)BOX_MAX_CHANNELS; i++) {
            chips[i].present = i < n;
        }
    }
    for (int i = 0; i < n; i++) {
        max31856_sim_set_temperature(&chips[i], codes[i]);
    }
    aux0 = aux;
    return true;
}

static void feed_fault(const char *p)
{
    int32_t ch, sr;
    if (parse_int(&p, 10u, 0, BOX_MAX_CHANNELS - 1, &ch) && parse_int(&p, 16u, 0, 0xFF, &sr) &&
        *skip_blanks(p) == '\0') {
        max31856_sim_set_fault(&chips[ch], (uint8_t)sr);
    }
}

void USART2_IRQHandler(void)
{
    if ((USART2_SR & USART_SR_RXNE) == 0u) {
        return;
    }
    uint32_t next = (ring_head + 1u) % FEED_RING;
    if (next == ring_tail) {
        /* Ring full: leave the byte in DR (QEMU then holds back the rest of the stream in its
         * socket) and stop interrupting; feed_byte() takes it when the ring has drained. */
        USART2_CR1 &= ~USART_CR1_RXNEIE;
        return;
    }
    ring[ring_head] = (uint8_t)USART2_DR;
    ring_head = next;
}

/* Next received feed byte, or -1 if none is waiting. */
static int feed_byte(void)
{
    if (ring_tail != ring_head) {
        uint8_t b = ring[ring_tail];
        ring_tail = (ring_tail + 1u) % FEED_RING;
        return b;
    }
    if ((USART2_CR1 & USART_CR1_RXNEIE) == 0u) { /* paused by a full ring: resume */
        int b = (USART2_SR & USART_SR_RXNE) ? (int)(uint8_t)USART2_DR : -1;
        USART2_CR1 |= USART_CR1_RXNEIE;
        return b;
    }
    return -1;
}

/* Take feed bytes from USART2. A completed S line advances the virtual clock to the next
 * sample instant and returns to the main loop, which then takes the sample; bytes on USART1
 * are handled by the main loop between calls (commands are answered at the current time).
 * With nothing to do the core sleeps until a byte arrives on either UART. */
bool hal_wait_for_event(uint32_t wake_at_ms)
{
    hal_watchdog_kick(); /* idle: the box would be kicking from its WFI loop */
    for (;;) {
        int byte = feed_byte();
        if (byte < 0) {
            /* Sleep with interrupts masked so one arriving between the check and the WFI
             * still wakes it; the handler runs once they are unmasked. USART1 is checked too:
             * a command's last byte taken by its ISR after the main loop read USART1 and
             * before the mask would otherwise sleep until a byte that never comes (no SysTick
             * here), and the host waits for the reply for good. */
            __asm volatile("cpsid i" ::: "memory");
            if (ring_tail == ring_head && !board_uart_rx_pending()) {
                __asm volatile("wfi" ::: "memory");
            }
            __asm volatile("cpsie i" ::: "memory");
            return true; /* the main loop looks at USART1, then calls again */
        }
        char c = (char)byte;
        if (c != '\n') {
            if (feed_len < FEED_LINE_MAX - 1u) {
                feed_line[feed_len++] = c;
            } else {
                feed_overlong = true;
            }
            continue;
        }
        feed_line[feed_len] = '\0';
        bool usable = !feed_overlong;
        feed_len = 0;
        feed_overlong = false;
        const char *p = skip_blanks(feed_line);
        char cmd = *p;
        if (!usable || cmd == '\0' || (p[1] != '\0' && p[1] != ' ' && p[1] != '\t')) {
            continue;
        }
        if (cmd == 'S' && feed_sample(p + 1)) {
            if ((int32_t)(wake_at_ms - now_ms) > 0) {
                now_ms = wake_at_ms;
            }
            return true;
        }
        if (cmd == 'F') {
            feed_fault(p + 1);
        }
    }
}

/* ---- retained memory ---------------------------------------------------------------------
 * QEMU's netduinoplus2 machine does not model the STM32F405's backup SRAM (its accesses land
 * on an unimplemented-device stub), so this board has none: every reset boots cold. */
size_t hal_retain_size(void)
{
    return 0u;
}

void hal_retain_read(size_t offset, void *dst, size_t n)
{
    (void)offset;
    (void)dst;
    (void)n;
}

void hal_retain_write(size_t offset, const void *src, size_t n)
{
    (void)offset;
    (void)src;
    (void)n;
}
