"""ManiSkill agents of the project; importing this package registers them (uid ``"prl_hand"``)."""

from envs.agents.prl_hand import PRLHand

__all__ = ["PRLHand"]
