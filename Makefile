# meshflow front door. `make demo` and `make test` are the whole quick start.
BUILD ?= build
JOBS ?= $(shell nproc)
CMAKE_FLAGS ?=

.PHONY: all deps build demo test install package test-cluster bench bench-speed bench-matrix corpus corpus-random pictures test-asan fuzz clean

all: build

deps:
	@scripts/install-deps

$(BUILD)/CMakeCache.txt:
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release $(CMAKE_FLAGS)

build: deps $(BUILD)/CMakeCache.txt
	cmake --build $(BUILD) -j $(JOBS)

demo: build
	$(BUILD)/meshflow run workflows/naca_wingtip.yaml

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

# Installs the program, its schemas and its documentation under PREFIX (bin/meshflow,
# share/meshflow/schemas, share/doc/meshflow); cmake/install.cmake says what goes where.
PREFIX ?= /usr/local
install: build
	cmake --install $(BUILD) --prefix $(PREFIX)

# The Debian package $(BUILD)/meshflow_<version>_<arch>.deb (CPack; install it with
# `apt install ./meshflow_*.deb`, which pulls in the libraries it declares).
package: build
	cd $(BUILD) && cpack -G DEB

# Snakemake on a single-node Slurm that the test starts on 127.0.0.1 (tests/cluster/slurm_test.sh;
# needs root and slurm-wlm, munge, snakemake from install-deps; skipped with the reason otherwise).
test-cluster: build
	cd $(BUILD) && ctest --output-on-failure -L cluster --timeout 1200

bench: build
	cmake --build $(BUILD) -j $(JOBS) --target benchmarks
	bench/run.sh $(BUILD)

# Issue 24's speed table alone (bench/speed.sh, ~25 min on 2 cores: the paper's wing beside Gmsh,
# DLR-F6, Rotor 67 cold, a split-only change, the cylinder), then RESULTS.md reassembled
bench-speed: build
	bench/speed.sh $(BUILD)
	bench/run.sh --assemble

# A 6-variant matrix of the demo from a cold cache: meshflow run -j 1, -j 2, Snakemake --cores 2
# (bench/matrix.sh, REPS=3 repetitions: ~15-25 min on 2 cores), then RESULTS.md reassembled
bench-matrix: build
	bench/matrix.sh $(BUILD)
	bench/run.sh --assemble

# Every file of both corpora (data/corpus, bench/corpus/real) through `meshflow init` and `meshflow run`, no hand
# edits: which end with a valid mesh and each failure's class, in bench/results/corpus.md (long: an hour or more)
corpus: build
	scripts/corpus.sh $(BUILD)

# N random CAD files for seed SEED (scripts/random-cad.py: wings, half wings, wing-bodies, propellers,
# finned bodies of revolution, ducts, filleted blocks, close bodies; STEP in metres, described in
# shapes.json) written to $(BUILD)/corpus-random-$(SEED), then through `meshflow init` and `meshflow run`
# like `corpus`: bench/results/corpus-random-$(SEED).md (long: each file may run up to TIMEOUT, 900 s)
SEED ?= 1
N ?= 100
corpus-random: build
	/usr/bin/python3 scripts/random-cad.py --seed $(SEED) --n $(N) --out $(BUILD)/corpus-random-$(SEED)
	scripts/corpus.sh $(BUILD) bench/results/corpus-random-$(SEED).md $(BUILD)/corpus-random-$(SEED)/*.step

# README's pictures (docs/img): demo and STEP wing meshes cut and rendered headless (VTK; own Xvfb without a DISPLAY)
pictures: build
	scripts/pictures.sh $(BUILD)

test-asan: deps
	cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DMESHFLOW_SANITIZE=ON $(CMAKE_FLAGS)
	cmake --build build-asan -j $(JOBS)
	cd build-asan && ASAN_OPTIONS=detect_leaks=0 ctest --output-on-failure -j $(JOBS) --timeout 1800

# libFuzzer targets (tests/fuzz), each for FUZZ_SECONDS; results in tests/fuzz/RESULTS.md.
FUZZ_SECONDS ?= 60
fuzz: deps
	cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ -DMESHFLOW_FUZZ=ON $(CMAKE_FLAGS)
	cmake --build build-fuzz -j $(JOBS) --target fuzzers
	tests/fuzz/run.sh build-fuzz $(FUZZ_SECONDS)

clean:
	rm -rf $(BUILD) build-asan build-fuzz
