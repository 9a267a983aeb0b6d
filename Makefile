# ground_texture_bow: the front door.
#   make demo   install dependencies, build, and run the main job on the built-in default: map
#               a floor with wheel odometry, save the map, localize on it 30 days later
#   make test   install dependencies, build in build/ws, run every gtest and rostest
#   make test-slow-disk  the same with every fsync delayed 200 ms (GTBOW_FSYNC_DELAY_MS) and
#                   both cores kept busy: the verdicts must not change
#   make test-sanitize  the same with AddressSanitizer + UndefinedBehaviorSanitizer (build/ws-asan),
#                       then the concurrency tests under ThreadSanitizer (build/ws-tsan)
#   make fuzz   the libFuzzer targets (clang), FUZZ_SECONDS each (default 600)
#   make screenshots  the README's pictures (docs/images): the localizer and the backend on a drive,
#                   then a later drive localized on the saved map, with RViz under Xvfb
#                   (scripts/screenshots.sh)
#   make test-arm  the SIMD kernels and their tests cross-built for aarch64, run under qemu-user
#   make soak   10 minutes of a 4x real-time replay through the nodelet with concurrent services
#   make benchmark  generate the default 32,000-image benchmark (once), evaluate every Table I
#                   row on it, and write docs/RESULTS.md with the plots
#   make bench-scaling  the scaling benchmark, 1,000 to 1,000,000 images (real, then synthetic),
#                   into docs/RESULTS.md
#   make bench-map  a 1,000,000-keyframe map through the node's Localizer: saved while keyframes
#                   and queries keep coming, loaded, answers compared; into docs/RESULTS.md
#   make benchmark-real  the presets on datasets cut from real floor photos (REAL_FLOORS, default
#                   ../shared/real_floors), a table per surface into docs/RESULTS.md
#   make benchmark-kernels  the timings under every Hamming kernel the CPU runs (avx512, avx2,
#                   popcnt, portable) on that real-floor data, the answers compared
#   make benchmark-authors  our presets beside the authors' choices (each alone and together)
#                   on the 4,000-image dataset issue 14 measured the authors' code on
#   make benchmark-verification  issue 15's verification ablation (wrong verified poses) on the
#                   real photographs and that dataset
#   make benchmark-keypoints  verification against the map's quantised keypoints beside the
#                   exact ones (issue 17), on make benchmark-real's data
# Each benchmark writes its section of docs/RESULTS.md and fails (after writing) when a target
# that README.md or docs/RESULTS.md claims is missed, or when an expected input (a surface, a
# split, a preset, a size) is absent. The targets are in scripts/targets.py.
SHELL := /bin/bash
# Debian's catkin lives in /usr/bin's python3; a pyenv python3 earlier on PATH cannot see it.
export PATH := /usr/bin:$(PATH)

WS        := $(CURDIR)/build/ws
JOBS      ?= $(shell nproc)
DEVEL     := $(WS)/devel
GTBOW     := $(DEVEL)/bin/gtbow
CATKIN    := catkin_make -C $(WS) -DCMAKE_BUILD_TYPE=Release -j$(JOBS)

BENCH_DATA ?= $(CURDIR)/build/benchmark/asphalt32k
BENCH_OUT  ?= $(CURDIR)/build/benchmark/eval

.PHONY: deps build demo test test-slow-disk test-sanitize test-arm fuzz soak benchmark bench-scaling \
  bench-map bench-data clean benchmark-real benchmark-kernels benchmark-authors benchmark-verification benchmark-keypoints

REAL_FLOORS ?= $(abspath $(CURDIR)/../shared/real_floors)

deps:
	@bash scripts/install_deps.sh

# The workspace's package directory mirrors the repository entry by entry (symlinks), leaving
# out build/: a symlink to the repository root would contain the workspace itself, and
# roslaunch's package walk (os.walk with followlinks) would loop until ELOOP.
.PHONY: ws-src
ws-src:
	@bash scripts/link_package.sh "$(CURDIR)" "$(WS)/src/ground_texture_bow"

build: deps ws-src
	@$(CATKIN) > $(CURDIR)/build/build.log 2>&1 || { tail -n 60 $(CURDIR)/build/build.log; echo "build failed: full log in build/build.log"; exit 1; }
	@echo "built: $(GTBOW)"

# The built-in default, the robot's whole story headless (scripts/backend_demo.sh): a floor
# with a 30 m drive and drifting wheel odometry; the localizer and pose_graph_backend map it
# with odometry alone (no ground truth), and the localizer saves the map with the backend's
# optimised keyframe poses; a fresh localizer in localization mode localizes a drive 30 days
# later on that map; a second mapping session on that day extends the map from wherever it
# starts; gtbow slam on the same drive finds the node's closures. Each figure is printed
# against the ground truth and its bound, and a missed bound fails the demo. Then the offline
# evaluation (gtbow eval) of the same floor.
demo: build
	@bash scripts/backend_demo.sh "$(WS)" build/demo
	@$(GTBOW) eval --dataset build/demo/floor --words 3000 --out build/demo/eval \
	  --cache build/cache --timing-queries 20 -q

test: deps ws-src
	@bash scripts/run_tests.sh "$(WS)" "$(JOBS)"

test-slow-disk: deps ws-src
	@bash scripts/run_tests.sh "$(WS)" "$(JOBS)" slow-disk

# Every gtest and rostest again, everything built with ASan + UBSan in its own workspace; any
# sanitizer report from any process (tests, nodes, the nodelet manager) fails the run.
# Then the concurrency tests (core, and the nodelet under concurrent service calls for
# TSAN_SECONDS, default 60) under ThreadSanitizer in build/ws-tsan (scripts/run_tsan.sh).
ASAN_WS := $(CURDIR)/build/ws-asan
TSAN_WS := $(CURDIR)/build/ws-tsan
test-sanitize: deps
	@bash scripts/link_package.sh "$(CURDIR)" "$(ASAN_WS)/src/ground_texture_bow"
	@bash scripts/run_tests.sh "$(ASAN_WS)" "$(JOBS)" sanitize
	@JOBS="$(JOBS)" bash scripts/run_tsan.sh "$(TSAN_WS)" "$(ASAN_WS)/build/ground_texture_bow/rostest_data"

# The Hamming and byte-distance kernels (OpenCV-free) with their tests, cross-built for aarch64
# (g++-aarch64-linux-gnu, static) and run under qemu-user for each GTBOW_SIMD value; installs
# the cross compiler and qemu when missing (scripts/test_arm.sh).
test-arm:
	@bash scripts/test_arm.sh "$(CURDIR)/build/arm"

# The file parsers under libFuzzer (test/fuzz): FUZZ_SECONDS per target (default 600), new
# inputs merged into test/fuzz/corpus.
fuzz: deps
	@bash scripts/fuzz.sh

# 10 minutes (SOAK_SECONDS) of a 4x real-time replay through the nodelet with concurrent
# service calls from a second process; figures into docs/RESULTS.md. Not part of make test.
soak: build
	@bash scripts/soak.sh "$(WS)"

# The paper's size: about 32,000 database images of asphalt, query days 0 to 180, a separate
# training area for the vocabularies (about 15 minutes to render on 2 cores, then about
# 30 minutes to evaluate).
# A rendering by an older renderer (synth.yaml's renderer_version) is rendered again.
RENDERER_VERSION := $(shell grep -oP 'kRendererVersion = \K[0-9]+' include/ground_texture_bow/eval/synth/generator.h)

bench-data: build
	@grep -qx "renderer_version: $(RENDERER_VERSION)" $(BENCH_DATA)/synth.yaml 2>/dev/null || \
	  $(GTBOW) synth --out $(BENCH_DATA) --force --surface asphalt \
	  --database-images 32000 --train 600 --queries 100 --days 0,30,90,180

benchmark: bench-data
	@$(GTBOW) eval --dataset $(BENCH_DATA) --ablation --out $(BENCH_OUT)
	@python3 scripts/write_results.py $(BENCH_OUT) docs; rc=$$?; \
	  python3 scripts/check_benchmark.py --full $(BENCH_OUT)/results.json || exit $$?; exit $$rc

# Memory, insertion, query (one and two threads), save and load from 1,000 to 1,000,000
# database images, both presets: the 32,085 real benchmark images, then synthetic postings
# sampled from their statistics (about 25 minutes; needs about 12 GB of RAM and 6 GB of disk).
bench-scaling: bench-data
	@$(GTBOW) bench-scaling --dataset $(BENCH_DATA) --out build/bench_scaling
	@python3 scripts/write_scaling.py build/bench_scaling docs

# The warehouse map through the node's engine (gtbow::Localizer), both presets: 1,000,000
# keyframes (the 32,085 real benchmark images, then synthetic ones), insertion, the map saved
# while keyframes and queries keep coming, loaded cold and warm, and the answers compared with
# those before the save. Needs about 15 GB of RAM and room for one map file (10+ GB) under
# build/bench_map. gtbow bench-map fails when an answer changed through the save and load; the
# section is written either way, and the target fails with either.
bench-map: bench-data
	@$(GTBOW) bench-map --dataset $(BENCH_DATA) --out build/bench_map; rc=$$?; \
	  python3 scripts/write_bench_map.py build/bench_map docs || exit $$?; exit $$rc

# Ten real floor photos (seven textured, three smooth concrete) as bounded regions, 320 x 240
# images at 0.5 mm per pixel, days 0 and 180, every preset; sequences and the maintained map
# (issue 28) on four renderings, the synthetic low-contrast floors and held-out photos (about 18
# minutes).
benchmark-real: build
	@bash scripts/benchmark_real.sh $(GTBOW) "$(REAL_FLOORS)" build/benchmark/real build/benchmark/real_eval

# The timings under every Hamming kernel the CPU runs (GTBOW_SIMD: avx512, avx2, popcnt,
# portable) on make benchmark-real's dataset: vocabulary training, and gtbow eval with every
# kernel on each timed query in turn (--timing-kernels); fails when a kernel's vocabulary,
# rankings or poses differ from the portable kernel's, or a claimed target is missed
# (docs/RESULTS.md, section "kernels"; about 10 minutes).
benchmark-kernels: build
	@bash scripts/benchmark_kernels.sh $(GTBOW) "$(REAL_FLOORS)" build/benchmark/real build/benchmark/kernels

# The dataset issue 14 measured the authors' code on (rendered once), our presets and each of
# the authors' choices alone and together (about 15 minutes).
benchmark-authors: build
	@bash scripts/benchmark_authors.sh $(GTBOW) build/benchmark/s4k build/benchmark/authors_eval

# Issue 15's verification ablation on the real photographs and the 4,000-image asphalt (needs
# make benchmark-real's dataset; renders the 4,000-image asphalt when absent, about 4 minutes;
# then about 5 minutes, 11 on a loaded machine):
# docs/RESULTS.md, sections "verification" and "descriptors" (each preset beside its variant
# without descriptors).
benchmark-verification: build
	@bash scripts/benchmark_verification.sh $(GTBOW) build/benchmark/real \
	  build/benchmark/s4k build/benchmark/verification_eval

# Issue 17's quantised keypoints: gtbow eval with and without --exact-keypoints on make
# benchmark-real's dataset, every verified pose compared (about 25 s with make benchmark-real's
# feature and vocabulary cache): docs/RESULTS.md, section "keypoints".
benchmark-keypoints: build
	@bash scripts/benchmark_keypoints.sh $(GTBOW) build/benchmark/real build/benchmark/keypoints_eval

clean:
	rm -rf build

# The README's pictures, taken under Xvfb (installs rviz, xvfb and imagemagick).
.PHONY: screenshots
screenshots: build
	@bash scripts/install_deps.sh --screenshots
	@bash scripts/screenshots.sh "$(WS)" build/screenshots docs/images
