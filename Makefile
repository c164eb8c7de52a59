# octofuse: set-up, build, tests and the main job on a Debian 12 machine.
#   make demo   - install everything and run the main job on the bundled data
#   make test   - install everything and run the whole test suite (C++ and Python)
#   make test-fast - the C++ tests and the Python tests not marked slow

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
JOBS ?= 2
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
APT_PACKAGES := build-essential cmake git python3-venv python3-dev \
                liboctomap-dev libeigen3-dev libgtest-dev octomap-tools libusb-1.0-0 openssl \
                chromium clang-format

.PHONY: all deps venv install lint format test test-fast test-cpp test-python test-python-fast demo bench fuzz clean

all: install

deps: ## Debian packages: compiler, CMake, OctoMap, Eigen, GoogleTest, OctoMap's tools
	@missing=""; for p in $(APT_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing:$$missing"; \
	  $(SUDO) apt-get update && $(SUDO) DEBIAN_FRONTEND=noninteractive apt-get install -y $$missing; \
	fi

$(PY): | deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip

venv: deps $(PY)

# what the installed package is built from: it is built again only when one of them changes
INSTALL_SOURCES := pyproject.toml CMakeLists.txt data/lab8.bag data/lab8_scene.json \
  $(shell find cpp python -type f \( -name '*.[ch]pp' -o -name '*.py' -o -name CMakeLists.txt \) \
          -not -path '*/__pycache__/*' 2>/dev/null)
INSTALLED := $(VENV)/.octofuse-installed

$(INSTALLED): $(PY) $(INSTALL_SOURCES) | deps
	$(PY) -m pip install "scikit-build-core>=0.10" "pybind11>=2.12"
	$(PY) -m pip install --no-build-isolation ".[test,ray,fleet,view]"
	touch $@

install: venv $(INSTALLED) ## build the C++ core (Release) and install octofuse with its test tools and viewer

test-cpp: deps ## C++ unit tests (GoogleTest via ctest)
	cmake -S . -B build/cpp-tests -DOCTOFUSE_BUILD_TESTS=ON -DCMAKE_BUILD_TYPE=Release
	cmake --build build/cpp-tests -j $(JOBS)
	ctest --test-dir build/cpp-tests --output-on-failure

test-python: install
	$(PY) -m pytest

test-python-fast: install
	$(PY) -m pytest -m "not slow"

CXX_SOURCES = $(shell find cpp tests/cpp -name '*.[ch]pp' | sort)

lint: install ## ruff (lint and format) and clang-format, checked
	$(VENV)/bin/ruff check python tests benchmarks
	$(VENV)/bin/ruff format --check python tests benchmarks
	clang-format --dry-run -Werror $(CXX_SOURCES)

format: install ## rewrite the sources in the project's style
	$(VENV)/bin/ruff check --fix python tests benchmarks
	$(VENV)/bin/ruff format python tests benchmarks
	clang-format -i $(CXX_SOURCES)

test: lint test-cpp test-python ## the whole suite, style included

test-fast: test-cpp test-python-fast ## the suite without the tests marked slow (subprocesses, end to end, browser, Ray, Zenoh, fuzz)

demo: install ## the main job on the bundled dataset
	$(VENV)/bin/octofuse demo

bench: install ## benchmarks (see benchmarks/README.md)
	$(PY) benchmarks/run_all.py

fuzz: install ## seeded fuzz campaign against the installed command (about 5 minutes)
	$(PY) benchmarks/fuzz_campaign.py --cases 3000 --minutes 5 --seed 1

clean:
	rm -rf build $(VENV) octofuse-demo
