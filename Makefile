# ground_texture_bow: the front door.
#   make demo   install dependencies, build, and run the main job on the built-in default
#   make test   install dependencies, build in build/ws, run every gtest and rostest
SHELL := /bin/bash
# Debian's catkin lives in /usr/bin's python3; a pyenv python3 earlier on PATH cannot see it.
export PATH := /usr/bin:$(PATH)

WS        := $(CURDIR)/build/ws
JOBS      ?= $(shell nproc)
DEVEL     := $(WS)/devel
GTBOW     := $(DEVEL)/bin/gtbow
CATKIN    := catkin_make -C $(WS) -DCMAKE_BUILD_TYPE=Release -j$(JOBS)

.PHONY: deps build demo test clean

deps:
	@bash scripts/install_deps.sh

$(WS)/src/ground_texture_bow:
	@mkdir -p $(WS)/src
	@ln -sfn $(CURDIR) $(WS)/src/ground_texture_bow

build: deps $(WS)/src/ground_texture_bow
	@$(CATKIN) > $(CURDIR)/build/build.log 2>&1 || { tail -n 60 $(CURDIR)/build/build.log; echo "build failed: full log in build/build.log"; exit 1; }
	@echo "built: $(GTBOW)"

demo: build
	@$(GTBOW) synth --out build/demo_floor --area 0.5 0.4 --train 40 --queries 20 --force
	@echo "Example images: build/demo_floor/images/database_000000.png, build/demo_floor/images/query_day180_000000.png"

test: deps $(WS)/src/ground_texture_bow
	@bash scripts/run_tests.sh "$(WS)" "$(JOBS)"

clean:
	rm -rf build
