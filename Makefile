# The README's two commands: `make demo` and `make test`. Both build .venv on first use.
PYTHON ?= $(shell PYENV_VERSION=3.12.1 pyenv which python3.12 2>/dev/null || command -v python3.12)
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: venv demo test lint bases benchmark clean

$(STAMP): pyproject.toml constraints.txt
	@test -n "$(PYTHON)" || { echo "python3.12 not found (pyenv install 3.12.1)"; exit 1; }
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -c constraints.txt -e ".[test,fastumi,benchmark,async]"
	# torchcodec cannot load without system FFmpeg here; LeRobot falls back to pyav (quietly, once removed)
	$(VENV)/bin/pip uninstall -y -q torchcodec || true
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	OMP_NUM_THREADS=1 $(VENV)/bin/dcdp-demo

test: $(STAMP)
	OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1 $(VENV)/bin/python -m pytest -q -n 2

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests scripts examples
	cd src && ../$(VENV)/bin/lint-imports --config ../pyproject.toml

benchmark: $(STAMP)
	OMP_NUM_THREADS=1 $(VENV)/bin/dcdp-benchmark

clean:
	rm -rf $(VENV) build *.egg-info
