# The two README commands. Both install what is missing into .venv first (idempotent).
VENV  := .venv
PY    := $(VENV)/bin/python
STAMP := $(VENV)/.installed
OUT   ?= results

.PHONY: setup run test clean
setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh web3d/static/package-lock.json
	bash scripts/setup.sh
	touch $(STAMP)

run: setup
	$(PY) -m bench run-default --out $(OUT)

# Lint and format checks first (fast), then the tests: one pytest worker per core (pytest-xdist), each test file
# on one worker, so a module's fixtures are built once. No test judges a wall-clock bound (those are `bench
# load`'s and the other benches'), so none has to run alone: the load tests share the machine like the rest.
test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n auto --dist loadfile

clean:
	rm -rf $(OUT) .pytest_cache
