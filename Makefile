# Two commands for a new machine: `make pipeline` (set-up + the main job) and `make test`.
.PHONY: setup pipeline test test-slow test-fast probe

export XDG_RUNTIME_DIR ?= /tmp/prl-runtime

setup:
	@bash scripts/setup.sh

pipeline: setup
	.venv/bin/prl-pipeline

test: setup
	@mkdir -p $(XDG_RUNTIME_DIR)
	.venv/bin/python -m pytest -q -m "not slow"

test-slow: setup
	@mkdir -p $(XDG_RUNTIME_DIR)
	.venv/bin/python -m pytest -q -m slow

test-fast: setup
	@mkdir -p $(XDG_RUNTIME_DIR)
	.venv/bin/python -m pytest -q -m "not sim and not train and not integration"

probe: setup
	.venv/bin/python -m envs.render_probe
