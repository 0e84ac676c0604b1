# Two commands do all set-up on a fresh machine:
#   make render   renders the report's scene into renders/
#   make test     runs the whole test suite
# Both create .venv, install the packages at the versions constraints.txt
# pins and make sure a libLLVM that Dr.Jit can use is present (installing
# libllvm19 with apt-get when possible).
# make test also installs Ray (the optional [cluster] extra), which the
# tests of the distributed backends need, and Debian's chromium, which the
# browser tests of compare's page drive through Playwright.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
CLUSTER_STAMP := $(VENV)/.installed-cluster

.PHONY: all render test validate bench llvm browser clean

all: render

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[test,validate]'
	touch $(STAMP)

$(CLUSTER_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -c constraints.txt -e '.[cluster]'
	touch $(CLUSTER_STAMP)

llvm: $(STAMP)
	@bash .ci/ensure-llvm.sh $(PY)

render: llvm
	mkdir -p renders
	$(PY) -m mitsuba_whitted.cli render scenes/cosc363.xml -o renders/cosc363.png

browser:
	@bash .ci/ensure-chromium.sh

test: llvm browser $(CLUSTER_STAMP)
	$(PY) -m pytest -q

validate: llvm
	$(PY) -m validation.run

bench: llvm
	$(PY) -m mitsuba_whitted.cli bench

clean:
	rm -rf $(VENV) renders .pytest_cache
