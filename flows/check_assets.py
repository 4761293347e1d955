"""Stage ``assets``: the hand model regenerates identically and the PLB catalogue loads (child run ``assets``)."""

from __future__ import annotations

from dataclasses import dataclass

from prefect import task
from prefect.cache_policies import NO_CACHE

from prl import tracking
from prl.plb import load_plb


@dataclass(frozen=True)
class Assets:
    """What the later stages build on: the hand URDF's digest and the Representation Space's shape."""

    hand_urdf_sha256: str
    plb_sizes: tuple[int, ...]
    plb_n_plans: int


@task(name="assets", cache_policy=NO_CACHE)
def assets_stage() -> Assets:
    """Check the generated hand URDF is up to date and the PLB catalogue is valid; log both."""
    import mlflow  # heavy: mlflow

    from envs.hand_model import verify_generated

    with tracking.child_run("assets"):
        plb = load_plb()
        assets = Assets(verify_generated(), tuple(int(s) for s in plb.sizes), int(plb.n_plans))
        mlflow.log_params({"hand_urdf_sha256": assets.hand_urdf_sha256, "plb_sizes": str(list(assets.plb_sizes)),
                           "plb_n_plans": assets.plb_n_plans})
    return assets
