# mocapkit — the two commands a newcomer runs: `make demo` and `make test`.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
STAMP  := $(VENV)/.installed
# torch (optional, neural methods): only a local CPU wheel is used, never a multi-GB CUDA build
TORCH_WHEEL := $(firstword $(wildcard /opt/wheels/torch-2.13.0*cpu*.whl))

.PHONY: demo test fuzz bench clean venv

$(PY):
	$(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)
	$(PIP) install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PIP) install -q -e ".[test]"
	$(if $(TORCH_WHEEL),$(PIP) install -q "$(TORCH_WHEEL)",@echo "no local torch CPU wheel: neural methods (bra, bra-p) and their tests are skipped; see README")
	touch $(STAMP)

venv: $(STAMP)

# Clean a bundled real CMU clip (corrupted with noise, outliers and gaps) with the
# default method and write a before/after report to demo_out/.
demo: $(STAMP)
	$(PY) -m mocapkit.demo --out demo_out

test: $(STAMP)
	$(PY) -m pytest -x -p no:cacheprovider

fuzz: $(STAMP)
	MOCAPKIT_FUZZ_EXAMPLES=2000 MOCAPKIT_FUZZ_RANDOM=1 $(PY) -m pytest -q tests -k fuzz

clean:
	rm -rf $(VENV) demo_out build *.egg-info
