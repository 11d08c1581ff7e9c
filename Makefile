# The two commands of the README. Both set up first (quick when nothing changed).
.PHONY: setup demo test

setup:
	@bash scripts/setup.sh

demo: setup
	@bash -c 'source ./env.sh && python scripts/demo.py'

test: setup
	@bash -c 'source ./env.sh && ruff check . && python -m pytest test'
