# Two commands for a new machine: `make pipeline` (set-up + the main job) and `make test`.
.PHONY: setup pipeline test test-fast probe

export XDG_RUNTIME_DIR ?= /tmp/prl-runtime
export HF_HUB_OFFLINE := 1

setup:
	@bash scripts/setup.sh

pipeline: setup
	.venv/bin/python -m flows.full_pipeline

test: setup
	@mkdir -p $(XDG_RUNTIME_DIR)
	.venv/bin/python -m pytest -q

test-fast: setup
	.venv/bin/python -m pytest -q -m "not sim and not train"

probe: setup
	.venv/bin/python -m envs.render_probe
