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

# Bytecode is written while the commands run: where PYTHONDONTWRITEBYTECODE is set (as in many CI images) each of
# the hundreds of processes the suite starts would compile the packages again (about 0.5 s per process that imports
# them), and each pytest worker would rewrite every test module it collects (9 s instead of 14). __pycache__ is
# ignored by git.
unexport PYTHONDONTWRITEBYTECODE

run: setup
	$(PY) -m bench run-default --out $(OUT)

# Lint and format checks first (fast), then the tests on pytest-xdist workers, two more than the cores (many tests
# wait on the servers, proxies and browsers they start, and beside other busy processes more workers take a larger
# share of the cores: with two busy loops on 2 cores pytest took 7:52 and 8:15 with 4 workers, 9:04 with 3), each
# test file on one worker so that a module's fixtures are built once, the files with slow tests handed out first
# (tests/conftest.py). No test judges a wall-clock bound (those are `bench load`'s and the other benches'), so none
# has to run alone. The Web3D page's JavaScript checker (npm run check in web3d/static/, TypeScript from its
# lockfile) runs as one of the tests, tests/web3d/test_page_checks.py, beside the others rather than before them.
WORKERS := $(shell echo $$(( $$(nproc) + 2 )))
test: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest -q -n $(WORKERS) --dist loadfile --no-loadscope-reorder

clean:
	rm -rf $(OUT) .pytest_cache
