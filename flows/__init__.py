"""Prefect flows and tasks of the PRL pipeline (thin over ``prl`` and ``envs``).

Prefect settings of this project, set here once (environment variables the user sets win): a temporary
Prefect API server (no ``PREFECT_API_URL``) gets 180 s to start, not Prefect's 20 s (a first start on a busy
or fresh machine migrates the local database; with a synthesis or a test suite running, 20 s is too short
and the flow never starts); no telemetry (there is no internet here).
"""

import os

import prl  # noqa: F401  (keeps the Hugging Face clients offline before any flow imports one)

os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
