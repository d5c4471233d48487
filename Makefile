# photonflow: the commands of the README.
#   make demo   set up .venv and run the main job
#   make test   set up .venv with test extras and run the whole test suite
#   make docs   set up .venv with docs extras and build the documentation site into site/
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# test files run in this many parallel workers (pytest-xdist; a file stays on one worker,
# so its module fixtures and compiled functions are shared as in a serial run)
TEST_WORKERS ?= 2

.PHONY: demo test docs lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@ $(VENV)/.installed

$(VENV)/.installed-docs: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install --quiet -e ".[docs]"
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	$(BIN)/photonflow demo

test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=15

# --strict: any warning (a broken link, a docstring mkdocstrings cannot parse) fails the
# build; NO_MKDOCS_2_WARNING silences mkdocs-material's end-of-life banner, not a warning
docs: $(VENV)/.installed-docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

lint: $(VENV)/.installed-test
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) demo_output .pytest_cache site
