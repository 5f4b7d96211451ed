# The two commands of the README: `make demo` (set up + run the demo job) and `make test`.
.PHONY: setup demo test benchmarks

setup:
	@bash deploy/setup.sh

demo: setup
	.venv/bin/mvpd demo

test: setup
	.venv/bin/python -m pytest

benchmarks:
	@EXTRAS=test,bench bash deploy/setup.sh
	@for bench in benchmarks/bench_*.py; do echo "== $$bench"; .venv/bin/python $$bench || exit 1; done
