# The two commands of the README. Both set up first (quick when nothing changed).
# `make compat`: the tests that need no ROS on Ubuntu 24.04's library versions (Python 3.12,
# its own venv .venv-compat; scripts/compat.sh), as CI runs after `make test`.
.PHONY: setup demo test compat

setup:
	@bash scripts/setup.sh

demo: setup
	@bash -c 'source ./env.sh && python scripts/demo.py'

test: setup
	@bash -c 'source ./env.sh && ruff check . && python -m pytest test'

compat:
	@bash scripts/compat.sh
