# C unit tests (cmocka), one binary per module, all built with ASan + UBSan.
# `make test` runs every one and prints cmocka's summary lines; included by ../Makefile.

TEST_BUILD := build/test
TEST_CC ?= gcc
SANITIZE := -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer
TEST_CFLAGS := $(WARN) -Wno-missing-prototypes -O1 -g $(SANITIZE) -D_DEFAULT_SOURCE \
               $(INCLUDES) -Ihal/native -Itest
TEST_LIBS := -lcmocka

# module -> its sources (the test file provides the fakes it needs)
TEST_SRC_max31856   := src/max31856.c hal/native/max31856_sim.c
TEST_SRC_axis_output := src/axis_output.c
TEST_SRC_cmd        := src/cmd.c
TEST_SRC_line       := src/line.c src/crc16.c

UNIT_TESTS := max31856 axis_output cmd line
UNIT_BINS := $(addprefix $(TEST_BUILD)/test_,$(UNIT_TESTS))

.SECONDEXPANSION:

$(TEST_BUILD)/test_%: test/test_%.c $$(TEST_SRC_$$*) $(wildcard include/*.h hal/*.h hal/native/*.h)
	@mkdir -p $(TEST_BUILD)
	$(TEST_CC) $(TEST_CFLAGS) $< $(TEST_SRC_$*) $(TEST_LIBS) -o $@

test: $(UNIT_BINS)
	@fail=0; for t in $(UNIT_BINS); do ./$$t || fail=1; done; exit $$fail
