# C unit tests (cmocka), one binary per module, all built with ASan + UBSan.
# `make test` runs every one and prints cmocka's summary lines; included by ../Makefile.

TEST_BUILD := build/test
TEST_CC ?= gcc
SANITIZE := -fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer
TEST_CFLAGS := $(WARN) -Wno-missing-prototypes -O1 -g $(SANITIZE) -D_DEFAULT_SOURCE \
               $(INCLUDES) -Iboards/native -Iemul -Itest
TEST_LIBS := -lcmocka

# module -> its sources (the test file provides the fakes it needs)
TEST_SRC_max31856   := src/max31856.c emul/max31856_sim.c
TEST_SRC_axis_output := src/axis_output.c
TEST_SRC_channel_guard := src/channel_guard.c
TEST_SRC_cmd        := src/cmd.c
TEST_SRC_line       := src/line.c src/crc16.c

UNIT_TESTS := max31856 axis_output channel_guard cmd line
UNIT_BINS := $(addprefix $(TEST_BUILD)/test_,$(UNIT_TESTS))

.SECONDEXPANSION:

$(TEST_BUILD)/test_%: test/test_%.c $$(TEST_SRC_$$*) $(wildcard include/*.h hal/*.h boards/native/*.h emul/*.h)
	@mkdir -p $(TEST_BUILD)
	$(TEST_CC) $(TEST_CFLAGS) $< $(TEST_SRC_$*) $(TEST_LIBS) -o $@


# ---- application tests: need a model header and host-generated expectations --------------
# The generator uses codegen and codegen.fixed from the project's venv.
MODEL_DIR := $(TEST_BUILD)/model
TEST_APP_CFG := -DBOX_MAX_CORRECTION_NM=40000 -DBOX_SLEW_NM_PER_S=700 -DBOX_COLD_START_SLEW=1
GEN_ARGS := --clamp-nm 40000 --slew-nm-per-s 700 --cold-start-slew 1
APP_TEST_SRC := $(filter-out src/model_binding.c,$(APP_SRC)) emul/max31856_sim.c \
                test/fake_board.c

$(MODEL_DIR)/vectors.h: test/gen_test_model.py $(wildcard ../thermal_comp/codegen/*.py ../thermal_comp/codegen/templates/*) \
                        ../thermal_comp/contract/terms.py
	@test -x $(PYTHON) || { echo "make test: $(PYTHON) not found: run 'make setup' at the top level (the application tests generate their model with codegen)." >&2; exit 2; }
	$(PYTHON) test/gen_test_model.py $(MODEL_DIR) $(GEN_ARGS)

$(MODEL_DIR)/model_test.h $(MODEL_DIR)/model_bad.h: $(MODEL_DIR)/vectors.h

$(TEST_BUILD)/test_app: test/test_app.c $(APP_TEST_SRC) src/model_binding.c $(MODEL_DIR)/vectors.h \
                        $(wildcard include/*.h hal/*.h test/*.h)
	$(TEST_CC) $(TEST_CFLAGS) $(TEST_APP_CFG) -I$(MODEL_DIR) \
	    -DBOX_MODEL_HEADER='"$(abspath $(MODEL_DIR)/model_test.h)"' \
	    $< $(APP_TEST_SRC) src/model_binding.c $(TEST_LIBS) -o $@

$(TEST_BUILD)/test_app_model_bad: test/test_app_model_bad.c $(APP_TEST_SRC) src/model_binding.c \
                                  $(MODEL_DIR)/vectors.h $(wildcard include/*.h hal/*.h test/*.h)
	$(TEST_CC) $(TEST_CFLAGS) $(TEST_APP_CFG) -I$(MODEL_DIR) \
	    -DBOX_MODEL_HEADER='"$(abspath $(MODEL_DIR)/model_bad.h)"' \
	    $< $(APP_TEST_SRC) src/model_binding.c $(TEST_LIBS) -o $@

APP_BINS := $(TEST_BUILD)/test_app $(TEST_BUILD)/test_app_model_bad

test: $(UNIT_BINS) $(APP_BINS)
	@fail=0; for t in $(UNIT_BINS) $(APP_BINS); do ./$$t || fail=1; done; exit $$fail
