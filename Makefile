# The two commands of the README. Both set up first (quick when nothing changed).
# `make compat`: the tests that need no ROS on Ubuntu 24.04's library versions (Python 3.12,
# its own venv .venv-compat; scripts/compat.sh), as CI runs after `make test`.
.PHONY: setup demo test check compat

setup:
	@bash scripts/setup.sh

demo: setup
	@bash -c 'source ./env.sh && python scripts/demo.py'

# Two workers, a test file each at a time (--dist loadfile: a file's fixtures stay in one
# process); the real-process tests mostly wait on their processes, and each picks a DDS
# domain no other process uses (testing/processes.py isolated_env).
test: setup
	@bash -c 'source ./env.sh && ruff check . && python -m pytest test -n 2 --dist loadfile'

# The fast tier for an edit-test loop: lint and the tests that start no process (no ROS node,
# no command line, no benchmark run); `make test` runs everything.
check: setup
	@bash -c 'source ./env.sh && ruff check . && python -m pytest test -q -m "not ros and not process"'

compat:
	@bash scripts/compat.sh
