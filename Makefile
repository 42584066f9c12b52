# Two commands on a fresh machine: `make demo` and `make test`.
# Both create .venv if it is missing and install only what changed since the
# last run (stamp files), so a second run starts at once.

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check -q
RUNTIME_STAMP := $(VENV)/.ext_observer-runtime
TEST_STAMP := $(VENV)/.ext_observer-test
BENCH_STAMP := $(VENV)/.ext_observer-bench

# Every process that starts a ROS node stays on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

.PHONY: all venv demo test coverage reproduce bench broad broad-data docs test-hosts hosts-report clean \
	mutation mutation-list ctrl-c-stress

all: test

$(PY):
	$(PYTHON) -m venv $(VENV)

# The package is installed in editable mode: the console scripts gyro_node,
# observer_node, monitor_node and imu_filter_node land in $(VENV)/bin and
# run this tree.
$(RUNTIME_STAMP): requirements.txt pyproject.toml setup.py setup.cfg package.xml resource/ext_observer $(wildcard config/*.yaml) | $(PY)
	$(PIP) install -r requirements.txt wheel
	$(PIP) install --no-deps --no-build-isolation --use-pep517 -e .
	touch $@

$(TEST_STAMP): requirements-test.txt $(RUNTIME_STAMP)
	$(PIP) install -r requirements-test.txt
	touch $@

venv: $(RUNTIME_STAMP)

demo: $(RUNTIME_STAMP)
	$(PY) -m ext_observer demo $(DEMO_ARGS)

# First the BROAD trials the tests read, fetched into data/broad where no
# folder holds them (test/broad_data.py; EXT_OBSERVER_BROAD_URL for a
# mirror). Then the whole suite on every core (pytest-xdist; each test has
# its own ROS domain, test/conftest.py), with the benchmark's own logic
# checks (test/benchmarks/); test/core/paper/test_observer.py checks in a fresh
# interpreter that the core imports no ROS.
# Then, with EXT_OBSERVER_COMPILED=0, what the plain kernels (a machine
# where numba cannot be installed) can break that the first run does not
# cover: the estimator's own known-answer tests, the calibration and the
# covariance on edge inputs, the plain batch in workers, one node process
# on plain kernels end to end (docs/tests.md says what is left out and why).
TEST_WORKERS ?= auto
PLAIN_TESTS := test/core/ahrs/test_ahrs_observer.py test/core/ahrs/test_ahrs_params.py \
	test/core/ahrs/test_ahrs_observer_robust.py test/core/ahrs/test_magcal.py \
	test/test_orientation_covariance.py test/core/ahrs/test_uncertainty.py test/broad/test_covariance.py \
	test/core/ahrs/test_compiled.py::test_the_whole_recording_loop_gives_the_per_sample_estimates \
	test/test_raw_imu_through_dds.py::test_drop_in_for_imu_filter_madgwick_as_a_process
PLAIN_DESELECT := $(foreach t,test_fixed_mode_reproduces_todays_imu_data_bit_for_bit \
	test_estimate_mode_publishes_the_pipelines_covariance_and_diagnostics \
	test_diagnostics_before_the_first_step_say_nan,--deselect test/test_orientation_covariance.py::$(t)) \
	--deselect test/broad/test_covariance.py::test_the_benchmark_writes_its_page_and_figures \
	--deselect test/core/ahrs/test_magcal.py::test_a_csv_and_a_bag_with_an_offset_calibrate_as_the_node_would

test: $(TEST_STAMP)
	$(PY) test/broad_data.py
	$(PY) -m pytest -n $(TEST_WORKERS) --dist worksteal $(PYTEST_ARGS) test
	EXT_OBSERVER_COMPILED=0 $(PY) -m pytest -n $(TEST_WORKERS) --dist worksteal $(PLAIN_DESELECT) $(PYTEST_ARGS) $(PLAIN_TESTS)

# Which lines of the raw-IMU path the suite runs (docs/tests.md#coverage):
# the suite under coverage.py, in-process code only (the node processes the
# tests start are not traced), then the report of core/ahrs.py and raw_imu.py.
coverage: $(TEST_STAMP)
	$(PY) -m coverage run --source=ext_observer -m pytest -q -p no:cacheprovider $(PYTEST_ARGS) test
	$(PY) -m coverage report -m --include='ext_observer/core/ahrs/ahrs_observer.py,ext_observer/core/ahrs/magcal.py,ext_observer/core/ahrs/uncertainty.py,ext_observer/pipeline/raw_imu.py'

# The paper's figures and Table 1, regenerated into docs/reproduction.md.
reproduce: $(RUNTIME_STAMP)
	$(PY) -m ext_observer reproduce --seeds 5 --docs docs

# The parameter tables of docs/parameters.md, from the nodes' parameter specs
# (test/test_docs.py fails while they differ).
docs: $(RUNTIME_STAMP)
	$(PY) -m ext_observer docs

$(BENCH_STAMP): requirements-bench.txt $(TEST_STAMP)
	$(PIP) install -r requirements-bench.txt
	touch $@

# Benchmarks print figures and write docs/performance.md; never a pass/fail.
bench: $(BENCH_STAMP)
	$(PY) -m bench $(BENCH_ARGS)

# The raw-IMU estimator and its anchors (VQF, BasicVQF, Madgwick, Mahony,
# Fusion) on the BROAD recordings, into docs/broad.md, docs/figures/broad_*.png
# and out/broad.json. Separate from `make bench`, which does not run it (it
# takes minutes and needs the data). The data: BROAD_DATA if given (a folder
# with BROAD's HDF5 files, directly or under data_hdf5/, as in a clone of
# BROAD), else $EXT_OBSERVER_BROAD_DATA, else data/broad (make broad-data),
# else ../shared/broad; with none, the command says so in one line.
# make broad BROAD_ARGS="--stress --json out/robustness.json": the robustness
# benchmark instead (each trial cut, biased, at 50 Hz, clipped),
# into docs/robustness.md, docs/figures/robustness.png and out/robustness.json.
# make broad BROAD_ARGS='--smooth --anchors VQF "offline VQF"': our smoothed
# estimate too, against VQF and offline VQF, into docs/offline.md's generated
# section and docs/figures/offline_error.png (with its covariance: a few minutes more).
BROAD_DATA ?=
BROAD_ARGS ?=

broad: $(BENCH_STAMP)
	$(PY) -m ext_observer broad $(if $(BROAD_DATA),--data $(BROAD_DATA)) --mode both --plain --json out/broad.json --docs docs $(BROAD_ARGS)

# BROAD (Laidig et al. 2021, CC BY 4.0) into data/broad/ (git-ignored): a
# shallow, sparse git clone of its HDF5 files, with trials.json and
# CREDIT.md (the citation and the licence). Needs git and github.com; a
# second run does nothing.
broad-data:
	$(PYTHON) ext_observer/broad/fetch.py data/broad

# The soak (test/test_soak.py): gyro, observer and monitor processes at 1 kHz
# for 60 s; memory flat, every input accounted for. Figures in out/soak.json.
# EXT_OBSERVER_SOAK_SECONDS, _RATE, _DEPTH and _MONITOR=0 change the setup.
soak: $(TEST_STAMP)
	$(PY) -m pytest -m soak -s $(PYTEST_ARGS) test/test_soak.py

# Two hosts over DDS (test/test_hosts.py, docs/across_machines.md): two
# network namespaces joined by a veth pair, loss and a partition with
# nftables, at 200 Hz; about 3 minutes. Root only: the first line checks
# (and as root installs iproute2 and nftables if missing), and fails with
# one line saying what is missing. Figures in out/hosts.json; make
# hosts-report draws them into docs/.
test-hosts:
	@$(PYTHON) test/netns.py check
	@$(MAKE) --no-print-directory $(TEST_STAMP)
	$(PY) -m pytest -m hosts -s $(PYTEST_ARGS) test/test_hosts.py

hosts-report: $(RUNTIME_STAMP)
	$(PY) test/hosts_report.py

# SIGINT and SIGTERM at random moments (docs/nodes.md#stopping-a-node):
# imu_filter_node and observer_node started CTRL_C_STARTS times on both
# executors, idle then with a busy loop on every core, each sent a signal
# 0.05-4 s after its start; the table counts clean ends, hangs, aborts and
# tracebacks. About 3 s a start; not part of make test.
CTRL_C_STARTS ?= 250
CTRL_C_ARGS ?=

ctrl-c-stress: $(TEST_STAMP)
	$(PY) stress/ctrl_c.py --starts $(CTRL_C_STARTS) $(CTRL_C_ARGS)

# Faults that matter (docs/tests.md#mutation): `make mutation-list`
# applies each mutant of mutation/mutants.toml in a copy of the tree and runs
# its tests (every one must be killed; about 3 minutes; MUTANTS="name ..."
# runs some). `make mutation` runs mutmut over the raw-IMU kernels, the
# calibration, the uncertainty and the pairing rules with their fast tests,
# one module after the other, each in out/mutmut/<module>/ (resumable; 4 to
# 20 minutes a module, about 75 minutes for all of it on 2 cores:
# MUTATION_ARGS="pairing.py" runs one module,
# "--report" prints the scores, "--survivors" reruns the survivors after
# tests were added). Neither is part of make test or CI.
MUTATION_STAMP := $(VENV)/.ext_observer-mutation
MUTANTS ?=
MUTATION_ARGS ?=

$(MUTATION_STAMP): requirements-mutation.txt $(TEST_STAMP)
	$(PIP) install -r requirements-mutation.txt
	touch $@

mutation-list: $(TEST_STAMP)
	$(PY) mutation/run_mutants.py $(MUTANTS)

mutation: $(MUTATION_STAMP)
	$(PY) mutation/run_mutmut.py $(MUTATION_ARGS)

clean:
	rm -rf $(VENV) build install log out .pytest_cache .hypothesis *.egg-info
