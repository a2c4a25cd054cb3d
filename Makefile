# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test test-quick bench lint api-docs clean

$(STAMP): pyproject.toml
	@if command -v apt-get >/dev/null 2>&1 && ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0; then \
		echo "installing apt package libusb-1.0-0 (needed by open3d)"; \
		(apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || \
		 (apt-get update -qq >/dev/null && apt-get install -y -qq libusb-1.0-0 >/dev/null)); \
	fi
	@if command -v apt-get >/dev/null 2>&1 && ! { [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ]; }; then \
		echo "installing apt packages chromium and chromium-driver (the tests open report.html in a headless browser)"; \
		(DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null 2>&1 || \
		 (apt-get update -qq >/dev/null && \
		  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null)); \
	fi
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/semmap demo --out outputs/demo

# The whole suite on two cores (pytest-xdist; a file's tests stay on one worker, so its module fixtures are built
# once), the 15 slowest tests listed at the end. CI runs this.
test: $(STAMP)
	$(BIN)/pytest -n 2 --dist loadfile --durations=15

# The fast core for the edit-test loop: every test not marked slow.
test-quick: $(STAMP)
	$(BIN)/pytest -n 2 --dist loadfile -m "not slow" --durations=15

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_octree_vs_octomap.py
	$(BIN)/python benchmarks/bench_sim.py

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks scripts

# API reference pages from the docstrings (docs/api/index.html; not committed)
api-docs: $(STAMP)
	rm -rf docs/api
	$(BIN)/pdoc --docformat restructuredtext --no-show-source -o docs/api \
		semmap semmap.types semmap.frame_arrays semmap.maps semmap.fusion semmap.io semmap.datasets semmap.config

clean:
	rm -rf $(VENV) outputs .pytest_cache
