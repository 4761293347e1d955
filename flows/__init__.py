"""Prefect flows and tasks of the PRL pipeline (thin over ``prl`` and ``envs``)."""

import os

# A temporary Prefect API server (no PREFECT_API_URL) gets 20 s to start by default; on a laptop that is
# already busy (a synthesis run, a test suite) that is too short and the flow never starts. 120 s, unless set.
os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
