# ns2codegen: logs/sim -> dataset -> train -> quantize -> export -> C inference
#
#   make export   train the built-in default model (if needed) and write the
#                 C headers + manifest to firmware/generated/
#   make test     the whole test suite (host C, cross-compiled Cortex-M4F build)
#   make bench    benchmarks, JSON on stdout (host training/inference, then the
#                 emulated Cortex-M4: instructions, cycles, budget, memory)
#   make firmware cross-build the library for the STM32F405 and print its size
PYTHON ?= python3
NS2 := $(PYTHON) -m ns2codegen.cli
GEN := firmware/generated
DEFAULT := build/default
CHECKPOINT ?= $(DEFAULT)/model.pt

.PHONY: all deps export test bench firmware clean

all: export

# ---------------------------------------------------------------- set-up
# torch first, pinned to the local CPU wheel (an unpinned install pulls CUDA).
deps: build/.deps-stamp
build/.deps-stamp: pyproject.toml scripts/install-deps.sh
	@mkdir -p build
	PYTHON=$(PYTHON) sh scripts/install-deps.sh
	@touch $@

# ---------------------------------------------------------------- pipeline
$(DEFAULT)/data.npz: config/default.toml | deps
	@mkdir -p $(DEFAULT)
	$(NS2) gen-data --kind downwash --samples-per-scenario 2000 --seed 0 --out $@

$(DEFAULT)/model.pt: $(DEFAULT)/data.npz config/default.toml
	$(NS2) train --data $< --out $@

export: deps $(CHECKPOINT)
	$(NS2) export $(CHECKPOINT) --out $(GEN)

# ---------------------------------------------------------------- checks
test: deps
	$(PYTHON) -m pytest tests

bench: deps
	@$(PYTHON) benchmarks/bench_core.py
	@$(PYTHON) benchmarks/bench_target.py

# Cortex-M4F cross build of the library: flash, RAM, worst-case stack (JSON)
firmware: deps $(GEN)/ns2_model_config.h
	$(PYTHON) -m ns2host.firmware_report $(GEN)
	$(PYTHON) -m ns2host.firmware_report $(GEN) --opt=-Os

$(GEN)/ns2_model_config.h:
	$(MAKE) export

clean:
	rm -rf build
