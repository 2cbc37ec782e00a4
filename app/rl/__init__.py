"""Reinforcement learning over handful's simulator: a Gymnasium environment (``env``) and the
paper's model-free baseline, REDQ, from a maintained library (``redq``). Benchmark methods only:
the trial service does not offer them (they need closed-loop control, which a hardware worker
does not run)."""

from app.rl.env import OBSERVATION_SETS, HandfulEnv, check_observations

__all__ = ["OBSERVATION_SETS", "HandfulEnv", "check_observations"]
