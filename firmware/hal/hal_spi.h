/* SPI bus with one chip select per device: the only way logic talks to the MAX31856s. */
#ifndef HAL_SPI_H
#define HAL_SPI_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Full-duplex transfer of len bytes with chip select `cs` asserted for the whole transfer
 * (SPI mode 1, MSB first). rx may equal NULL. Returns false if `cs` does not exist or the bus
 * did not complete (timeout); rx is then unspecified. */
bool hal_spi_transfer(uint8_t cs, const uint8_t *tx, uint8_t *rx, size_t len);

#endif
