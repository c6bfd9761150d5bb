# ns2codegen: logs/sim -> dataset -> train -> quantize -> export -> C inference
#
#   make export   train the built-in default model (if needed) and write the
#                 C headers + manifest to firmware/generated/
#   make test     the whole test suite (host C, cross-compiled Cortex-M4F build)
#   make bench    benchmarks, JSON on stdout (host training/inference, then the
#                 emulated Cortex-M4: instructions, cycles, budget, memory; the
#                 app's 1 ms stabilizer iteration next to the stock estimator/controller)
#   make export-onboard  the same with the one-tick on-board variant of the
#                 network (narrower intermediate layers, H and L of the paper)
#   make firmware cross-build the library for the STM32F405 and print its size
#   make app      the Crazyflie firmware with the app (build/app/cf2.elf, cf2.bin)
#                 and its size report (JSON: stock, with the app, the difference);
#                 NS2_INFER=fixed|float|both selects the inference paths,
#                 NS2_TABLES=ram puts the fixed-point phi tables in SRAM
#   make fuzz     inference, sliced API, peer table, controller and HIL parser
#                 under ASan + UBSan, FUZZ_COUNT structured inputs (JSON report)
PYTHON ?= python3
NS2 := $(PYTHON) -m ns2cli
GEN := firmware/generated
DEFAULT := build/default
ONBOARD := build/onboard
CHECKPOINT ?= $(DEFAULT)/model.pt

.PHONY: all deps export export-onboard test bench firmware app fuzz sim paper-data ablation clean

all: export

# ---------------------------------------------------------------- set-up
# torch first, pinned to the local CPU wheel (an unpinned install pulls CUDA).
deps: build/.deps-stamp
build/.deps-stamp: pyproject.toml scripts/install-deps.sh
	@mkdir -p build
	PYTHON=$(PYTHON) sh scripts/install-deps.sh
	@touch $@

# ---------------------------------------------------------------- pipeline
$(DEFAULT)/data.npz: ns2codegen/default.toml | deps
	@mkdir -p $(DEFAULT)
	$(NS2) gen-data --kind downwash --samples-per-scenario 2000 --seed 0 --out $@

$(DEFAULT)/model.pt: $(DEFAULT)/data.npz ns2codegen/default.toml
	$(NS2) train --data $< --out $@

export: deps $(CHECKPOINT)
	$(NS2) export $(CHECKPOINT) --out $(GEN)

$(ONBOARD)/model.pt: $(DEFAULT)/data.npz ns2codegen/default.toml
	@mkdir -p $(ONBOARD)
	$(NS2) train --data $< --out $@ --onboard

export-onboard: deps $(ONBOARD)/model.pt
	$(NS2) export $(ONBOARD)/model.pt --out $(GEN)

# ---------------------------------------------------------------- checks
test: deps
	$(PYTHON) -m pytest tests

bench: deps
	@$(PYTHON) benchmarks/bench_core.py
	@$(PYTHON) benchmarks/bench_target.py
	@$(PYTHON) benchmarks/bench_stabilizer.py
	@$(PYTHON) benchmarks/bench_sim.py
	@$(PYTHON) benchmarks/bench_plan.py

# Cortex-M4F cross build of the library: flash, RAM, worst-case stack (JSON)
firmware: deps $(GEN)/ns2_model_config.h
	$(PYTHON) -m ns2host.firmware_report $(GEN)
	$(PYTHON) -m ns2host.firmware_report $(GEN) --opt=-Os

$(GEN)/ns2_model_config.h:
	$(MAKE) export

# crazyflie-firmware (CRAZYFLIE_BASE=..., the ../shared tarball unpacked under build/, or
# a git fetch of the pinned commit there: host/crazyflie.py)
# with the app; `make -C firmware/app cload` flashes build/app/cf2.bin
NS2_INFER ?= fixed
NS2_TABLES ?= flash
app: deps $(GEN)/ns2_model_config.h
	$(PYTHON) -m ns2host.cfapp $(GEN) --out build/app --infer $(NS2_INFER) --tables $(NS2_TABLES)

# Structured fuzzing under -fsanitize=address,undefined (fuzz/ns2_fuzz.c, host/fuzz.py);
# a bounded run of the same drivers is part of `make test` (tests/test_fuzz.py).
FUZZ_COUNT ?= 1000000
FUZZ_SEED ?= 1
fuzz: deps $(GEN)/ns2_model_config.h
	$(PYTHON) -m ns2host.fuzz --gen $(GEN) --count $(FUZZ_COUNT) --seed $(FUZZ_SEED)

# Simulated flights -> data -> model, two curriculum rounds, then the swap and ring
# experiments: build/sim/results/swaps.json, rings.json (a row per case and controller:
# BL, BL-tuned, NN, NN-default, Mellinger), gain_search.json, tables (.md) and plots.
# SIM_SECONDS per team.
SIM := build/sim
SIM_SECONDS ?= 120
# one torch thread: the default count thrashes on a loaded 2-core machine (20-60x slower)
sim paper-data ablation: export OMP_NUM_THREADS ?= 1
$(SIM)/round1.npz: | deps $(GEN)/ns2_model_config.h
	@mkdir -p $(SIM)
	$(NS2) sim collect --seconds-per-team $(SIM_SECONDS) --seed 1 --out $@
$(SIM)/model1.pt: $(SIM)/round1.npz
	$(NS2) train --data $< --out $@ --quiet
$(SIM)/gen1/ns2_model_config.h: $(SIM)/model1.pt
	$(NS2) export $< --out $(SIM)/gen1
$(SIM)/round2.npz: $(SIM)/gen1/ns2_model_config.h
	$(NS2) sim collect --gen $(SIM)/gen1 --learned fixed --seconds-per-team $(SIM_SECONDS) --seed 2 --out $@
$(SIM)/model2.pt: $(SIM)/round1.npz $(SIM)/round2.npz
	$(NS2) train --data $(SIM)/round1.npz --data $(SIM)/round2.npz --out $@ --quiet
$(SIM)/gen2/ns2_model_config.h: $(SIM)/model2.pt
	$(NS2) export $< --out $(SIM)/gen2
sim: $(SIM)/gen2/ns2_model_config.h
	$(NS2) sim swaps --gen $(SIM)/gen2 --out $(SIM)/results
	$(NS2) sim rings --gen $(SIM)/gen2 --out $(SIM)/results

# The paper-sized simulated data set (1.4 M samples), the 5 networks trained on it,
# the H/L ablation (about half an hour on 2 cores; JSON in build/paper_data.json)
paper-data: deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py > build/paper_data.json.tmp && mv build/paper_data.json.tmp build/paper_data.json
	@cat build/paper_data.json

# The paper's ablations (benchmarks/ablation.py: H, L, without relative velocity,
# sum of pairwise models, type-agnostic deep set; 3 seeds, trained to convergence)
# on the paper-sized simulated data set, plus a test set of larger teams: about 2 h on
# the 2-core machine, one torch thread per training (docs/ground-truth.md);
# ABLATION_DEVICE=cuda trains on a GPU.
ABLATION_DEVICE ?= cpu
build/paper_data.npz: | deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py --data-only --out $@
# the larger-team test set: teams of 4 and 5 robots, never seen in training
build/larger_teams.npz: | deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py --data-only --team-sizes 4,5 --samples 200000 --seed 8 --out $@
ablation: build/paper_data.npz build/larger_teams.npz
	$(PYTHON) benchmarks/ablation.py --data build/paper_data.npz --test-data build/larger_teams.npz \
		--seeds 3 --lr-drops 2 --device $(ABLATION_DEVICE) \
		> build/ablation.json.tmp && mv build/ablation.json.tmp build/ablation.json
	@cat build/ablation.json

clean:
	rm -rf build
