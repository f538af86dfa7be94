# Board variant qemu_uartfeed (boards/qemu_uartfeed/qemu_board.c, docs/hil.md): the STM32F405
# image for `qemu-system-arm -M netduinoplus2`, samples fed over USART2 instead of SPI.
#   make BOARD=qemu_uartfeed MODEL=../build/model.h   -> build/qemu_uartfeed/qemu_uartfeed.elf
# Same compiler, flags, startup, linker script, USART1 and watchdog files as BOARD=stm32f405;
# only the board file (clock, SPI, ADC, time) is replaced. Included by ../../Makefile.

QEMU_BOARD_SRC := boards/stm32f405/startup.c boards/stm32f405/uart.c boards/stm32f405/watchdog.c \
                  emul/max31856_sim.c $(wildcard boards/qemu_uartfeed/*.c)

$(BUILD)/qemu_uartfeed.elf: $(APP_SRC) $(QEMU_BOARD_SRC) boards/stm32f405/stm32f405.ld \
                            $(wildcard include/*.h hal/*.h boards/stm32f405/*.h emul/*.h) \
                            $(MODEL_ABS) $(BUILD)/flags
	$(ARM_CC) $(ARM_CFLAGS) -Iemul $(MODEL_DEF) $(APP_SRC) $(QEMU_BOARD_SRC) \
	    $(ARM_LDFLAGS) -o $@
