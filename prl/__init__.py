"""The PRL library: Physical Laws Bank, labels, demos, LeRobot export, features, RN, LN (never imports Prefect).

Nothing in this project downloads at run time: the text model ships in a package and datasets are local,
so the Hugging Face clients are told to stay offline before any of them is imported (``setdefault``: a user
who wants the hub sets ``HF_HUB_OFFLINE=0``). Every entry point imports ``prl`` first.
"""

import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
