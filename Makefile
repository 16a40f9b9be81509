# Two commands (see README): `make run` sets up and runs the main job, `make test` sets up
# and runs the tests. Both create ./.venv on first use and reuse it afterwards.
PYTHON ?= python3
VENV ?= .venv
# CPU build of torch; pinned so pip takes the local wheel instead of a multi-GB CUDA build.
TORCH ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: setup run test clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check "$(TORCH)"
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e ".[dev]"
	touch $@

run: setup
	$(BIN)/sumo-scimm eval --routes town12_short --resume

test: setup
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) .pytest_cache
