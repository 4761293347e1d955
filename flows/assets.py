"""Prefect task: verify the assets (hand model regenerates identically, PLB catalogue loads)."""

from __future__ import annotations

from prefect import task
from prefect.cache_policies import NO_CACHE


@task(name="verify-assets", cache_policy=NO_CACHE)
def verify_assets() -> dict[str, object]:
    """Check the generated hand URDF is up to date and the PLB catalogue is valid; return a summary."""
    from envs.hand_model import verify_generated
    from prl.plb import load_plb

    plb = load_plb()
    return {"hand_urdf_sha256": verify_generated(), "plb_sizes": list(plb.sizes), "plb_n_plans": plb.n_plans}
