"""ManiSkill3 side of PRL. Importing ``envs`` registers the ``"prl_hand"`` agent and the ``PRL-*`` tasks."""

from envs import agents, tasks  # noqa: F401
