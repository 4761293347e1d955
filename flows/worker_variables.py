"""The environment variables of the pipeline's worker processes (Dask workers, the plan trials' processes)."""

from __future__ import annotations


def worker_variables() -> dict[str, str]:
    """Environment variables for local worker processes (the synthesis' Dask workers, the plan trials' processes): the Prefect
    API URL this process uses, Dask's logs at warnings only.

    When ``PREFECT_API_URL`` is unset, Prefect's temporary server of this process is started (if it
    is not yet) and its URL is passed on, so workers report to it instead of starting their own.
    """
    from prefect.client.orchestration import get_client  # heavy: prefect
    from prefect.settings import PREFECT_API_URL

    url = PREFECT_API_URL.value()
    if not url:
        with get_client(sync_client=True) as client:
            url = str(client.api_url)
    return {"PREFECT_API_URL": str(url).rstrip("/"), "DASK_LOGGING__DISTRIBUTED": "warning"}
