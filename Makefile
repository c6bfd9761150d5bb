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

.PHONY: all deps export export-onboard test bench firmware app flash fuzz sim paper-data ablation real calibrate sim-adapt results clean

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
# two workers (pytest-xdist), a test file each at a time: its fixtures are built once
TEST_WORKERS ?= 2
test: deps
	$(PYTHON) -m pytest -n $(TEST_WORKERS) --dist loadfile tests

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
# a git fetch of the pinned commit there: host/crazyflie.py) with the app; `make flash
# URI=radio://...` or `make flash SWARM=crazyflies.yaml` writes build/app/cf2.bin through
# cflib's bootloader (ns2 flash, docs/flying.md)
NS2_INFER ?= fixed
NS2_TABLES ?= flash
app: deps $(GEN)/ns2_model_config.h
	$(PYTHON) -m ns2host.cfapp $(GEN) --out build/app --infer $(NS2_INFER) --tables $(NS2_TABLES)

flash: deps
	$(PYTHON) -m ns2cli flash build/app/cf2.bin $(if $(SWARM),--swarm $(SWARM),--uri $(URI))

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
# rough (default): a real Crazyflie's effects fitted to the real flights (`make calibrate`); or clean
SIMULATOR ?= rough
# one torch thread: the default count thrashes on a loaded 2-core machine (20-60x slower)
sim paper-data ablation real: export OMP_NUM_THREADS ?= 1
build/real/%: export OMP_NUM_THREADS ?= 1
$(SIM)/round1.npz: | deps $(GEN)/ns2_model_config.h
	@mkdir -p $(SIM)
	$(NS2) sim collect --sim $(SIMULATOR) --seconds-per-team $(SIM_SECONDS) --seed 1 --out $@
$(SIM)/model1.pt: $(SIM)/round1.npz
	$(NS2) train --data $< --out $@ --quiet
$(SIM)/gen1/ns2_model_config.h: $(SIM)/model1.pt
	$(NS2) export $< --out $(SIM)/gen1
$(SIM)/round2.npz: $(SIM)/gen1/ns2_model_config.h
	$(NS2) sim collect --sim $(SIMULATOR) --gen $(SIM)/gen1 --learned fixed --seconds-per-team $(SIM_SECONDS) --seed 2 --out $@
$(SIM)/model2.pt: $(SIM)/round1.npz $(SIM)/round2.npz
	$(NS2) train --data $(SIM)/round1.npz --data $(SIM)/round2.npz --out $@ --quiet
$(SIM)/gen2/ns2_model_config.h: $(SIM)/model2.pt
	$(NS2) export $< --out $(SIM)/gen2
sim: $(SIM)/gen2/ns2_model_config.h
	$(NS2) sim swaps --sim $(SIMULATOR) --gen $(SIM)/gen2 --out $(SIM)/results
	$(NS2) sim rings --sim $(SIMULATOR) --gen $(SIM)/gen2 --out $(SIM)/results


# The paper-sized simulated data set (1.4 M samples), the 5 networks trained on it,
# the H/L ablation (about 20 min on 2 cores; JSON in build/paper_data.json)
paper-data: deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py --sim $(SIMULATOR) --workers 2 > build/paper_data.json.tmp && mv build/paper_data.json.tmp build/paper_data.json
	@cat build/paper_data.json

# The paper's ablations (benchmarks/ablation.py: H, L, without relative velocity,
# sum of pairwise models, type-agnostic deep set; 3 seeds, trained to convergence)
# on the paper-sized simulated data set, plus a test set of larger teams; one torch
# thread per training, ABLATION_WORKERS trainings at once (the same results): on the
# 2 cores about 8 min for the data sets and 34 min for the trainings two at once (76 min
# in all one at a time; docs/ground-truth.md); ABLATION_DEVICE=cuda trains on a GPU
# (one at a time). The data sets are kept per simulator.
# Every training is kept under $(RUNS)/<experiment>/ as it finishes (committed: a rerun, by anyone,
# trains only what is missing); NS2_SCHEDULER=tcp://host:8786 trains on a Dask cluster
# (docs/experiments.md).
RUNS ?= docs/results/runs
ABLATION_DEVICE ?= cpu
ABLATION_WORKERS ?= $(if $(filter cpu,$(ABLATION_DEVICE)),2,1)
build/paper_data-%.npz: | deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py --sim $* --workers 2 --data-only --out $@
# the larger-team test set: teams of 4 and 5 robots, never seen in training
build/larger_teams-%.npz: | deps
	@mkdir -p build
	$(PYTHON) benchmarks/paper_data.py --sim $* --workers 2 --data-only --team-sizes 4,5 --samples 200000 --seed 8 --out $@
ablation: build/paper_data-$(SIMULATOR).npz build/larger_teams-$(SIMULATOR).npz
	$(PYTHON) benchmarks/ablation.py --data build/paper_data-$(SIMULATOR).npz --test-data build/larger_teams-$(SIMULATOR).npz \
		--seeds 3 --lr-drops 2 --device $(ABLATION_DEVICE) --workers $(ABLATION_WORKERS) --runs $(RUNS)/ablation \
		> build/ablation.json.tmp && mv build/ablation.json.tmp build/ablation.json
	@cat build/ablation.json

# The paper's own flights (docs/real-flights.md): the authors' uSD logs of 16 June 2020
# (../shared/neural-swarm-data) -> aligned, labelled, cut data sets; the paper's network
# (H = 20, L = 4, REAL_SEEDS seeds) under the paper's random split and trained without
# the held-out flights; the ablations scored on the held-out flights; the authors'
# published networks as a peer; the chosen model exported to C and every held-out
# sample through it. JSON, tables and plots in build/real/.
REAL := build/real
REAL_SEEDS ?= 3
REAL_ABLATION_SEEDS ?= 3
REAL_EPOCHS ?= 30
REAL_AXES ?= H L V P T
REAL_TRAIN = $(PYTHON) benchmarks/ablation.py --config $(REAL)/real.toml --max-epochs $(REAL_EPOCHS) \
	--patience 3 --lr-drops 1 --batch-size 1024 --runs $(RUNS)/real-trainings
REAL_HELD = --data $(REAL)/train.npz --test-data $(REAL)/heldout.npz --test-label held_out_flights
REAL_HISTORY ?=
$(REAL)/all.npz: | deps
	$(NS2) real data --out $(REAL) $(if $(REAL_HISTORY),--history-ms $(REAL_HISTORY)) --quiet
# the paper's protocol: all flights, the random 80/20 split of 50 pieces per scenario
$(REAL)/paper.json: $(REAL)/all.npz
	$(REAL_TRAIN) --data $(REAL)/all.npz --axes paper --seeds $(REAL_SEEDS) --save-dir $(REAL)/paper > $@.tmp && mv $@.tmp $@
# trained without the held-out flights (every fifth of each scenario), scored on them
$(REAL)/heldout.json: $(REAL)/all.npz
	$(REAL_TRAIN) $(REAL_HELD) --axes paper --seeds $(REAL_SEEDS) --save-dir $(REAL)/heldout > $@.tmp && mv $@.tmp $@
# the ablations, one JSON per axis (they run side by side with make -j)
$(REAL)/ablation-%.json: $(REAL)/all.npz
	$(REAL_TRAIN) $(REAL_HELD) --axes $* --no-reference --seeds $(REAL_ABLATION_SEEDS) > $@.tmp && mv $@.tmp $@
# leave one collection out: the paper's network trained on the other collections (blind.json scores it)
REAL_COLLECTIONS := 2019-12-11 2019-12-20 2020-06-16
$(REAL)/loco-%.json: $(REAL)/all.npz
	$(REAL_TRAIN) --data $(REAL)/without-$*.npz --axes paper --seeds $(REAL_SEEDS) --save-dir $(REAL)/loco-$* > $@.tmp && mv $@.tmp $@
# the blind scores: overall, in the wake, per scenario; plain and mass-neutral; both mass conventions
$(REAL)/blind.json: $(foreach c,$(REAL_COLLECTIONS),$(REAL)/loco-$(c).json) $(REAL)/heldout.json $(REAL)/authors.pt
	$(NS2) real blind --dir $(REAL) --authors $(REAL)/authors.pt --seeds $(REAL_SEEDS) --out $@
# on-board adaptation judged on the blind splits (issue 53 item 4, docs/adaptation.md): every robot's
# flight through the host C's label and adaptation (any export builds it: the held-out network's)
$(REAL)/adapt-gen/ns2_model_config.h: $(REAL)/heldout.json
	$(NS2) export $(REAL)/heldout/H-20-seed0.pt --out $(REAL)/adapt-gen --quiet
$(REAL)/adapt.json: $(REAL)/blind.json $(REAL)/adapt-gen/ns2_model_config.h
	$(NS2) real adapt --dir $(REAL) --gen $(REAL)/adapt-gen --seeds $(REAL_SEEDS) --quiet --out $@
# the wake's memory (issue 52): the blind splits with every neighbour's state also 50, 100 and
# 200 ms ago (model.history_ms), in a folder of their own; every collection left out and the
# held-out flights (12 trainings, about 25 min on one free core), or fewer with REAL_MEM_SPLITS
REAL_MEM_SPLITS ?= $(REAL_COLLECTIONS) heldout
REAL_MEM_LAGS ?= 50,100,200
$(REAL)-mem/blind.json: $(REAL)/authors.pt
	$(MAKE) REAL=$(REAL)-mem REAL_HISTORY=$(REAL_MEM_LAGS) $(foreach c,$(filter-out heldout,$(REAL_MEM_SPLITS)),$(REAL)-mem/loco-$(c).json) \
		$(if $(filter heldout,$(REAL_MEM_SPLITS)),$(REAL)-mem/heldout.json)
	$(NS2) real blind --dir $(REAL)-mem --authors $(REAL)/authors.pt --seeds $(REAL_SEEDS) \
		$(foreach c,$(REAL_MEM_SPLITS),--collection $(c)) --out $@
$(REAL)/memory.json: $(REAL)/blind.json $(REAL)-mem/blind.json
	$(NS2) real memory --now $(REAL)/blind.json --past $(REAL)-mem/blind.json --out $@
# the authors' published networks (trained on all their collections, these flights included)
$(REAL)/authors.pt: $(REAL)/all.npz
	$(NS2) real import-authors build/neural-swarm-data/models/models/output --out $@
$(REAL)/authors.json: $(REAL)/authors.pt
	$(NS2) real score --checkpoint $< --data-dir $(REAL) --out $@
# the export: the network with the wake's memory (REAL_MEM_LAGS; section 10 of docs/real-flights.md)
# trained under the paper's protocol on every flight of all three collections (one seed), and its C
# checked on every held-out sample of that data
$(REAL)-mem/paper.json: | deps
	$(MAKE) REAL=$(REAL)-mem REAL_HISTORY=$(REAL_MEM_LAGS) REAL_SEEDS=1 $@
$(REAL)/gen/ns2_model_config.h: $(REAL)-mem/paper.json
	$(NS2) export $(REAL)-mem/paper/H-20-seed0.pt --out $(REAL)/gen --quiet
$(REAL)/c_check.json: $(REAL)/gen/ns2_model_config.h
	$(NS2) real check-c --gen $(REAL)/gen --checkpoint $(REAL)-mem/paper/H-20-seed0.pt --data-dir $(REAL)-mem --out $@
real: $(REAL)/paper.json $(REAL)/heldout.json $(foreach a,$(REAL_AXES),$(REAL)/ablation-$(a).json) \
		$(REAL)/authors.json $(REAL)/c_check.json $(REAL)/blind.json $(REAL)/memory.json $(REAL)/adapt.json
	$(NS2) real report --dir $(REAL) --checkpoint $(REAL)/heldout/H-20-seed0.pt

# The simulator against the real flights (docs/simulator.md, "A simulator as rough as a
# real Crazyflie"): fit the rough simulator's parameters and the z law read off the logs
# (written as rough.toml and read_law.toml beside calibration.md: copy them over
# host/sim/params/rough.toml and paper/params/read_law.toml to adopt them), replay the
# real swaps with the authors' network in the loop; every swap flight of the collection
# (56), or the first CALIBRATE_PER_SCENARIO of each swap folder if set.
CALIBRATE_PER_SCENARIO ?=
calibrate: export OMP_NUM_THREADS ?= 1
$(REAL)/authors-gen/ns2_model_config.h: $(REAL)/authors.pt
	$(NS2) export $< --out $(REAL)/authors-gen --quiet
calibrate: $(REAL)/all.npz $(REAL)/authors-gen/ns2_model_config.h
	$(NS2) sim calibrate --logs build/neural-swarm-data --data-dir $(REAL) --gen $(REAL)/authors-gen \
		$(if $(CALIBRATE_PER_SCENARIO),--per-scenario $(CALIBRATE_PER_SCENARIO)) --workers 2 --out $(SIM)/calibration

# The on-board adaptation judged in flight, in the simulator (docs/adaptation.md, issue 53
# item 5): the authors' network in the rough simulator, BL-tuned / NN / NN+adapt with an
# unmodelled 3 g, swaps, 5-robot rings and a battery to the low-voltage limit (48 flights,
# about 12 min on 2 cores): build/sim-adapt/adapt.json, adapt.md
sim-adapt: export OMP_NUM_THREADS ?= 1
sim-adapt: $(REAL)/authors-gen/ns2_model_config.h
	$(NS2) sim adapt --sim $(SIMULATOR) --gen $(REAL)/authors-gen --out build/sim-adapt --workers 2

# README's results table and the docs' tables rewritten from the committed result files
# (docs/results/runs/, ns2 results, docs/experiments.md); COLLECT="sim real ..." first copies those
# experiments' stamped JSONs from build/ into docs/results/runs/ (then commit them with the tables)
COLLECT ?=
results: | deps
	$(NS2) results $(foreach e,$(COLLECT),--collect $(e))

clean:
	rm -rf build
