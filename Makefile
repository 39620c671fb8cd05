# ident-opt: the two commands a newcomer needs are `make identify` and `make test`.
# Both create .venv and install what they need on first use (Python >= 3.11 and gcc are all it takes).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PROBLEM ?= problems/tudor_2dof.toml

.PHONY: identify test test-arms lint bench codegen audit arms calibration clean-venv fuzz online-arms excitation-arms cutoff-study real-arms

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test]'
	touch $(STAMP)

## The main job: every step on the real MERIt/TUDOR trials; tables, figures and reports into results/; then the
## DFKI double pendulum (a second real robot: train on 8 trajectories, test on a swing-up) into results/dfki/.
## Each report records what it wrote and results/README.md is rebuilt from those records: any order works.
## Last, design A.0 of the DFKI pendulum (other hardware; train on a swing-up, test on open-loop sines) into
## results/dfki_a0/.
identify: $(STAMP)
	$(BIN)/ident-opt audit    --problem problems/tudor_2dof_paper.toml --out results
	$(BIN)/ident-opt compare  --problem $(PROBLEM) --out results --json results/compare.json
	$(BIN)/ident-opt online   --problem $(PROBLEM) --out results --json results/online.json
	$(BIN)/ident-opt diagnose --problem $(PROBLEM) --data data/merit/exp1.csv --data data/merit/exp2.csv \
	    --out results/diagnosis --json results/diagnosis/diagnosis.json
	$(BIN)/ident-opt identify --problem $(PROBLEM) --out results --json results/identify.json
	$(BIN)/ident-opt compare  --problem problems/dfki_c0.toml --no-progress \
	    --json results/dfki/compare.json
	$(BIN)/ident-opt identify --problem problems/dfki_c0.toml --no-variants --json results/dfki/identify.json
	$(BIN)/ident-opt compare  --problem problems/dfki_a0.toml --no-progress \
	    --json results/dfki_a0/compare.json
	$(BIN)/ident-opt identify --problem problems/dfki_a0.toml --no-variants --json results/dfki_a0/identify.json

## The whole test suite (2 workers).
test: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q

## The whole n-joint diagnosis test matrix (tests/test_diagnose_arm.py; make test runs its shorter cases): ~15 min.
test-arms: $(STAMP)
	IDENT_OPT_ARM_MATRIX=1 $(BIN)/python -m pytest -n 2 -q tests/test_diagnose_arm.py

## The long hostile-input fuzz (tests/test_fuzz.py: data, problem, command line, stream; tests/test_stream_start.py:
## the stream's first samples; tests/test_fuzz_inputs.py: URDF, n-joint columns, ROS 2 bags, trial gaps, output
## paths; tests/test_fuzz_hostile.py: fleet layouts and --logs URLs, output path kinds, the API's argument shapes;
## the suite runs a small share of each): FUZZ_EXAMPLES cases per property (14 properties, >= 11,200 cases in all;
## the fleet's: its layout scan every case, the whole command one case in 12), each logged to build/fuzz.log, then
## summed up (cases per property; tracebacks, NaN, modified inputs, partial outputs, hangs, specials replaced).
FUZZ_EXAMPLES ?= 800
fuzz: $(STAMP)
	mkdir -p build && rm -f build/fuzz.log
	IDENT_OPT_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) IDENT_OPT_FUZZ_LOG=build/fuzz.log $(BIN)/python -m pytest -n 2 -q \
	    tests/test_fuzz.py tests/test_stream_start.py::test_fuzz_stream_start tests/test_fuzz_inputs.py \
	    tests/test_fuzz_hostile.py
	$(BIN)/python -m tests.test_fuzz build/fuzz.log

## Style: ruff's lint rules (with complexity limits, see pyproject.toml) and its formatter, checked not applied.
## The diagnosis on every shipped real robot: each arm's page into results/<arm>/diagnosis/, and
## results/diagnosis/real_arms.md generated from the verdicts the tool gives (about 5 minutes on 2 cores).
real-arms: $(STAMP)
	$(BIN)/python benchmarks/real_arms.py

lint: $(STAMP)
	$(BIN)/ruff check ident_opt tests benchmarks
	$(BIN)/ruff format --check ident_opt tests benchmarks

## Generated C for the default problem: C sources, shared library, parameters.json, README.
codegen: $(STAMP)
	$(BIN)/ident-opt codegen --problem $(PROBLEM) --out build/codegen

audit: $(STAMP)
	$(BIN)/ident-opt audit --problem problems/tudor_2dof_paper.toml --out results

## Excitation design, proved in the simulator (not part of `identify`: about 5 min on 2 cores):
## D-, cond-optimal and discriminating 20 s trajectories against MERIt-like and random ones, 10 noise seeds each.
excitation: $(STAMP)
	$(BIN)/ident-opt excite --problem $(PROBLEM) --proof 10 --out results/excitation.md --no-progress

## The shipped n-joint arms (KUKA LWR4+, Panda, TX40): compare and identify each into results/<arm>/ (about 1.5 min
## on 2 cores; not part of `identify`, which keeps to the planar arms' 3-minute budget).
ARMS := kuka_lwr4 franka_panda staubli_tx40
arms: $(STAMP)
	for p in $(ARMS); do \
	    $(BIN)/ident-opt compare --problem problems/$$p.toml --no-progress --json results/$$p/compare.json && \
	    $(BIN)/ident-opt identify --problem problems/$$p.toml --json results/$$p/identify.json || exit 1; \
	done

## Online identification on the real n-joint arms (results/online_arms.md: KUKA, Panda, TX40): the replay against
## from-scratch re-solves, the generated update against Python and its time, the stream on t, q and currents only.
online-arms: $(STAMP)
	$(BIN)/python benchmarks/online_arms.py --out results

## The D-optimal excitation against random Fourier motions within the same limits and duration, on the 7-joint KUKA
## (rigid inverse dynamics + noise) and the planar arm (the closed-loop simulator), 20 unseen noise seeds each
## (results/excitation_arms.md; about 15 min on 2 cores). The base frequencies were chosen on the development seeds
## (0-4); seeds 1000-1019 were looked at once after that (results in git history, abc5cb1), 3000-3019 decide.
excitation-arms: $(STAMP)
	$(BIN)/python benchmarks/excitation_benefit.py --problem problems/kuka_lwr4.toml --base-hz 0.2 \
	    --problem $(PROBLEM) --base-hz 0.1 --seeds 20 --unseen-from 3000 --no-progress --out results

## The simulator's default trial against the real exp1 (results/simulator_calibration.md); col10-col13 are
## the MERIt trials' strain gauges.
calibration: $(STAMP)
	$(BIN)/ident-opt calibrate --problem problems/tudor_sim.toml --real $(PROBLEM) \
	    --channel col10 --channel col11 --channel col12 --channel col13 --out results

## Where the derivative cut-off rule and the recommended fit stand in simulation, against the best cut-off in
## hindsight and a cross-validated yardstick (results/cutoff_study_<seeds>.md; about 3 min per set of three seeds on
## 2 cores, 15 min for the ten fresh ones). SEEDS=tuning|unseen|fresh.
SEEDS ?= tuning
cutoff-study: $(STAMP)
	$(BIN)/python benchmarks/cutoff_study.py --seeds $(SEEDS) --out results

## Benchmarks: each prints ratios measured side by side in one run; the output is kept in results/benchmarks/.
bench: $(STAMP)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test,bench]'
	mkdir -p results/benchmarks
	@set -e; for b in benchmarks/bench_*.py; do \
	  echo "== $$b"; $(BIN)/python $$b | tee results/benchmarks/$$(basename $$b .py).txt; done

clean-venv:
	rm -rf $(VENV)
