# Quick start: `make demo` and `make test` on a fresh machine (each sets up .venv itself).
PY      ?= python3.11
VENV    := .venv
VPY     := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
OUT     ?= out/demo

.PHONY: venv test test-sl demo bench bench-all extension clean

$(STAMP): pyproject.toml
	test -x $(VPY) || $(PY) -m venv $(VENV)
	$(VPY) -m pip install -q --upgrade pip
	$(VPY) -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(VPY) -m pytest -q

test-sl: $(STAMP)
	$(VPY) -m pytest -q tests/sl

demo: $(STAMP)
	$(VPY) -m datapipe demo --out $(OUT) --force

bench: $(STAMP)
	$(VPY) benchmarks/bench_sl.py

# every report under benchmarks/results/ (about 30 min on 2 cores)
bench-all: bench
	$(VPY) benchmarks/bench_pipeline.py
	$(VPY) benchmarks/bench_sl_render.py
	$(VPY) benchmarks/bench_bop.py
	$(VPY) benchmarks/bench_ray.py

clean:
	rm -rf $(VENV) out build dist *.egg-info

include make/extension.mk
