#include "fake_board.h"

#include <string.h>

#include "hal_aux.h"
#include "hal_board.h"
#include "hal_retain.h"
#include "hal_spi.h"
#include "hal_time.h"
#include "hal_uart.h"
#include "hal_watchdog.h"

max31856_sim_t fake_chips[FAKE_N_CHIPS];
uint32_t fake_now_ms;
int32_t fake_aux;
bool fake_aux_ok;
bool fake_reset_by_watchdog;
uint32_t fake_watchdog_timeout_ms;
uint32_t fake_watchdog_kicks;
uint32_t fake_board_inits;

static char tx[FAKE_TX_SIZE + 1];
static size_t tx_len;
static char rx[1024];
static size_t rx_len, rx_pos;

void fake_board_reset(void)
{
    for (int i = 0; i < FAKE_N_CHIPS; i++) {
        max31856_sim_reset(&fake_chips[i]);
    }
    fake_now_ms = 0;
    fake_aux = 0;
    fake_aux_ok = true;
    fake_reset_by_watchdog = false;
    fake_retain_clear();
    fake_watchdog_timeout_ms = 0;
    fake_watchdog_kicks = 0;
    fake_board_inits = 0;
    tx_len = 0;
    rx_len = rx_pos = 0;
}

void fake_uart_send(const char *s)
{
    size_t n = strlen(s);
    if (rx_pos == rx_len) {
        rx_pos = rx_len = 0;
    }
    if (n > sizeof rx - rx_len) {
        n = sizeof rx - rx_len;
    }
    memcpy(rx + rx_len, s, n);
    rx_len += n;
}

const char *fake_uart_take(void)
{
    tx[tx_len] = '\0';
    tx_len = 0;
    return tx;
}

bool hal_spi_transfer(uint8_t cs, const uint8_t *txb, uint8_t *rxb, size_t len)
{
    if (cs >= FAKE_N_CHIPS) {
        return false;
    }
    max31856_sim_transfer(&fake_chips[cs], txb, rxb, len);
    return true;
}

void hal_uart_write(const uint8_t *data, size_t len)
{
    if (len > FAKE_TX_SIZE - tx_len) {
        len = FAKE_TX_SIZE - tx_len;
    }
    memcpy(tx + tx_len, data, len);
    tx_len += len;
}

size_t hal_uart_read(uint8_t *buf, size_t max)
{
    size_t n = rx_len - rx_pos;
    if (n > max) {
        n = max;
    }
    memcpy(buf, rx + rx_pos, n);
    rx_pos += n;
    return n;
}

uint32_t hal_millis(void)
{
    return fake_now_ms;
}

bool hal_wait_for_event(uint32_t wake_at_ms)
{
    (void)wake_at_ms;
    return false;
}

void hal_watchdog_start(uint32_t timeout_ms)
{
    fake_watchdog_timeout_ms = timeout_ms;
}

void hal_watchdog_kick(void)
{
    fake_watchdog_kicks++;
}

bool hal_reset_was_watchdog(void)
{
    return fake_reset_by_watchdog;
}

bool hal_reset_was_warm(void)
{
    return fake_reset_by_watchdog;
}

bool hal_aux_read(uint8_t index, int32_t *value)
{
    if (index != 0u || !fake_aux_ok) {
        return false;
    }
    *value = fake_aux;
    return true;
}

void hal_board_init(void)
{
    fake_board_inits++;
}

/* Retained memory (backup SRAM): kept across fake resets until fake_retain_clear(). */
uint8_t fake_retained[4096]; /* as the F405's backup SRAM */

void fake_retain_clear(void)
{
    memset(fake_retained, 0xA5, sizeof fake_retained); /* a power cut leaves garbage */
}

size_t hal_retain_size(void)
{
    return sizeof fake_retained;
}

void hal_retain_read(size_t offset, void *dst, size_t n)
{
    memcpy(dst, fake_retained + offset, n);
}

void hal_retain_write(size_t offset, const void *src, size_t n)
{
    memcpy(fake_retained + offset, src, n);
}
