# The two commands of README.md. Both work on a fresh clone of a fresh Debian 12 machine.
.PHONY: run test

HOST ?= 127.0.0.1
PORT ?= 8000
# pytest-xdist workers for `make test` (0: one process, e.g. for -s or --pdb); tests that share the one
# LinuxCNC sim go to one worker (xdist_group, tests/conftest.py)
PYTEST_WORKERS ?= 2

run:  ## set up and start the service (SQLite under ./var, example library loaded)
	scripts/bootstrap.sh run
	.venv/bin/setupcam serve --host $(HOST) --port $(PORT)

test:  ## set up and run the whole test suite (SQLite and PostgreSQL, browser, controller sim)
	scripts/bootstrap.sh test
	.venv/bin/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadgroup $(PYTEST_ARGS)
