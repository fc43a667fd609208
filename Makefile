# Two entry points: `make bake` (set up, build, run the bundled example) and `make test`.
# Every step is idempotent: stamps and dependency lists make a second run skip what is done.

PYTHON  ?= python3
VENV    := .venv
PY      := $(VENV)/bin/python
HIRAD   := $(VENV)/bin/hirad
CPP_SRC := $(shell find pipeline formats -name '*.h' -o -name '*.cpp') CMakeLists.txt
CPP_TESTS := $(wildcard tests/cpp/*.cpp)
DEB_PACKAGES := g++ cmake ninja-build pkg-config python3-dev python3-venv \
                libembree-dev libtbb-dev libopenexr-dev libeigen3-dev libgtest-dev time \
                libzstd-dev liblz4-dev libxxhash-dev libopenvdb-dev libboost-iostreams-dev \
                libpango-1.0-0 libpangoft2-1.0-0 libharfbuzz-subset0
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
JOBS := $(shell nproc)

.PHONY: bake test engine cpp-test py-test bench clean

bake: engine
	$(HIRAD) bake configs/cornell_hierarchical.yaml

test: engine cpp-test py-test

engine: .stamp-engine

# Debian packages: installed only when one of them is missing.
.stamp-apt: Makefile
	@if dpkg-query -W -f='$${Status}\n' $(DEB_PACKAGES) 2>/dev/null | grep -vq "install ok installed" \
	    || [ $$(dpkg-query -W -f='$${Status}\n' $(DEB_PACKAGES) 2>/dev/null | wc -l) -lt $(words $(DEB_PACKAGES)) ]; then \
	  echo "installing Debian packages: $(DEB_PACKAGES)"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(DEB_PACKAGES); \
	fi
	@touch $@

.stamp-venv: pyproject.toml .stamp-apt
	@[ -x $(PY) ] || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "scikit-build-core>=0.10" "nanobind>=2.0" \
	    $$($(PY) -c "import tomllib;d=tomllib.load(open('pyproject.toml','rb'))['project'];print(' '.join(repr(x) for x in d['dependencies']+d['optional-dependencies']['test']+d['optional-dependencies']['bench']))" | tr -d "'")
	@touch $@

# The C++ engine as the Python extension hirad._engine (editable: Python files are used in place).
# The editable install maps each Python file when it is made: a new or moved module needs it again.
PY_SRC := $(shell find tools/hirad -name '*.py')
.stamp-engine: .stamp-venv $(CPP_SRC) $(PY_SRC)
	$(PY) -m pip install -q --no-build-isolation --no-deps -e .
	@touch $@

build/cpp/hirad_tests: .stamp-apt $(CPP_SRC) $(CPP_TESTS)
	cmake -S . -B build/cpp -G Ninja -DHIRAD_BUILD_TESTS=ON -DHIRAD_BUILD_PYTHON=OFF -DCMAKE_BUILD_TYPE=Release > /dev/null
	cmake --build build/cpp -j $(JOBS)

cpp-test: build/cpp/hirad_tests
	cd build/cpp && ctest --output-on-failure -j $(JOBS)

py-test: engine .stamp-web
	$(PY) -m pytest -q tests/python

# The glTF export's real renderer and validator (tests/python/outputs/test_gltf.py): Debian's
# Chromium (headless, WebGL on its SwiftShader) and, from npm, three.js, the Khronos glTF
# Validator and playwright-core, pinned by tests/web/package-lock.json. Node.js comes from the
# machine; Debian's nodejs and npm are installed only when there is no node at all.
WEB_PACKAGES := chromium fonts-dejavu-core
.stamp-web: Makefile tests/web/package.json tests/web/package-lock.json
	@if dpkg-query -W -f='$${Status}\n' $(WEB_PACKAGES) 2>/dev/null | grep -vq "install ok installed" \
	    || [ $$(dpkg-query -W -f='$${Status}\n' $(WEB_PACKAGES) 2>/dev/null | wc -l) -lt $(words $(WEB_PACKAGES)) ] \
	    || ! command -v npm > /dev/null; then \
	  pkgs="$(WEB_PACKAGES)"; command -v node > /dev/null || pkgs="$$pkgs nodejs"; command -v npm > /dev/null || pkgs="$$pkgs npm"; \
	  echo "installing Debian packages: $$pkgs"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$pkgs; \
	fi
	cd tests/web && npm ci --no-audit --no-fund --loglevel=error
	@touch $@

bench: engine
	$(PY) bench/run.py

# The link store's libFuzzer target (not part of `test`): built with clang and sanitizers,
# run for 60 s. New inputs go to a scratch directory, never into the seed corpus.
FUZZ_PACKAGES := clang libclang-rt-14-dev libzstd-dev liblz4-dev libxxhash-dev
FUZZ_FLAGS := -std=c++17 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined
.PHONY: fuzz

.stamp-apt-fuzz: Makefile
	@if dpkg-query -W -f='$${Status}\n' $(FUZZ_PACKAGES) 2>/dev/null | grep -vq "install ok installed" \
	    || [ $$(dpkg-query -W -f='$${Status}\n' $(FUZZ_PACKAGES) 2>/dev/null | wc -l) -lt $(words $(FUZZ_PACKAGES)) ]; then \
	  echo "installing Debian packages: $(FUZZ_PACKAGES)"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(FUZZ_PACKAGES); \
	fi
	@touch $@

build/fuzz/linkstore_fuzz: .stamp-apt-fuzz tests/fuzz/linkstore_fuzz.cpp formats/linkstore.cpp formats/linkstore.h
	@mkdir -p build/fuzz
	clang++ $(FUZZ_FLAGS) -I. tests/fuzz/linkstore_fuzz.cpp formats/linkstore.cpp -lzstd -llz4 -lxxhash -o $@

fuzz: build/fuzz/linkstore_fuzz
	rm -rf build/fuzz/scratch && mkdir -p build/fuzz/scratch
	build/fuzz/linkstore_fuzz -max_total_time=60 -artifact_prefix=build/fuzz/ build/fuzz/scratch tests/fuzz/corpus/linkstore

clean:
	rm -rf build out .stamp-*
