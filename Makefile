# One command each: `make demo` runs the paper's experiment, `make test` the test suite.
# Both create the virtual environment (.venv) themselves when it is missing or stale.
# `make docs` builds the documentation site into site/ (`make test` builds it too, strictly,
# then checks its pages' layout in headless Chromium: `make docs-layout`).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Material for MkDocs prints a notice about MkDocs 2.0 on every build; it is not a warning.
MKDOCS := NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs

# Every page of the built site/ at 1280 px in headless Chromium: a table or code block cut
# or scrolling sideways, or text cut, fails it (docs/scripts/check_layout.py); a screenshot
# of each page goes to .cache/docs-screenshots/. A missing Chromium is installed with
# apt-get where this is root with apt-get; where it cannot be, the check says so and is
# skipped without failing the target.
LAYOUT_CHECK := $(BIN)/python docs/scripts/check_layout.py site .cache/docs-screenshots \
	--install-browser --skip-without-browser

.PHONY: demo test docs docs-layout bench bench-quick lint format clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/jaxpose reproduce --out results

# pyright and the strict docs build (then its layout check) run beside the test suite at
# the lowest priority: they take a core only when a test worker leaves one idle. Their
# reports are printed after the tests; any of the three failing fails the target. The
# notebooks the docs build executes share the tests' program cache (and their XLA
# options, which the cache's folder depends on): a program one of them compiled, the
# other loads.
TEST_CACHE := JAXPOSE_CACHE_DIR=$(CURDIR)/.pytest_cache/jaxpose \
	XLA_FLAGS="--xla_force_host_platform_device_count=1 --xla_cpu_use_fusion_emitters=false"
test: $(STAMP)
	$(BIN)/ruff check .
	nice -n 19 $(BIN)/pyright > .pyright.log 2>&1 & pyright=$$!; \
	$(TEST_CACHE) nice -n 19 sh -c '$(MKDOCS) build --strict --site-dir site && $(LAYOUT_CHECK)' \
		> .mkdocs.log 2>&1 & docs=$$!; \
	$(BIN)/python -m pytest -n 2 --dist loadfile --no-loadscope-reorder --durations=40; \
	status=$$?; wait $$pyright || status=1; wait $$docs || status=1; \
	cat .pyright.log .mkdocs.log; exit $$status

docs: $(STAMP)
	$(MKDOCS) build --strict --site-dir site

docs-layout: $(STAMP)
	$(LAYOUT_CHECK)

# The speed targets table (benchmarks/speed.py's TARGETS beside their figures) prints last.
bench: $(STAMP)
	$(BIN)/python -m benchmarks.p3p_rate --n 100000
	$(BIN)/python -m benchmarks.startup
	$(BIN)/python -m benchmarks.distortion
	$(BIN)/python -m benchmarks.recognition
	$(BIN)/python -m benchmarks.run

bench-quick: $(STAMP)
	$(BIN)/python -m benchmarks.p3p_rate --n 20000 --out /tmp/p3p_rate_quick.json
	$(BIN)/python -m benchmarks.startup --quick
	$(BIN)/python -m benchmarks.distortion --quick
	$(BIN)/python -m benchmarks.recognition --quick
	$(BIN)/python -m benchmarks.run --quick

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff check --fix .
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) results site docs/generated .pytest_cache .hypothesis .pyright.log .mkdocs.log \
		.cache/docs-screenshots
