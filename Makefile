# humanoid_reach_ros: `make demo` runs the main job, `make test` the tests.
# Both set up what is missing first (tools/setup.sh is idempotent and quick when done).
SHELL := /bin/bash
ENV := . tools/env.sh &&
PYTEST_ARGS ?=
# make test runs the test files on this many pytest-xdist workers (one file stays on one worker,
# so its module fixtures are built once); TEST_WORKERS=0 runs them in this process, one by one.
# The files go out in collection order, heaviest first (test/conftest.py HEAVY_FIRST): xdist's own
# order (most tests first) left the one-test graph files, the longest, for the end.
# Two on two cores: three took 7:01 instead of 8:56 on a fresh clone (the graph tests wait on
# real-time motions), but the load made two graph tests fail in two runs (both since made robust)
TEST_WORKERS ?= 2

.PHONY: setup test lint demo up bench bench-graph bags clean urdf bench-peers

setup:
	@tools/setup.sh

# the linter first (ruff.toml); a finding stops make before the tests
test: setup
	@$(ENV) ruff check .
	@$(ENV) python -m pytest test $(if $(filter-out 0,$(TEST_WORKERS)),-n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder) $(PYTEST_ARGS)

lint: setup
	@$(ENV) ruff check .

demo: setup
	@$(ENV) python -m humanoid_reach_ros.demo $(if $(ROBOT),--robot $(ROBOT)) $(if $(PLANT),--plant $(PLANT))

# the whole graph (the six nodes with their YAML files, as reach.launch.py) until Ctrl-C
up: setup
	@$(ENV) hr_graph $(if $(ROBOT),--robot $(ROBOT)) $(if $(PLANT),--plant $(PLANT))

bench: setup
	@$(ENV) for b in bench/graph.py $$(ls bench/*.py | grep -v '^bench/graph.py$$'); do echo "== $$b"; python $$b || exit 1; done

bench-graph: setup
	@$(ENV) python bench/graph.py

# Peers side by side (bench/peers, docs/peers.md): own venvs .venv-peers/.venv-placo, never part of setup/test.
bench-peers: setup
	@bench/peers/setup.sh
	@$(ENV) python bench/peers/run.py $(PEERS_ARGS)

bags: setup
	@$(ENV) python tools/record_bags.py

urdf: setup
	@$(ENV) python tools/gen_hrp2_urdf.py

clean:
	rm -rf build install log .pytest_cache
