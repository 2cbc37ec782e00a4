"""Reinforcement learning over handful's simulator: a Gymnasium environment (``app.rl.env``),
and the paper's model-free baseline, REDQ, from a maintained library (``app.rl.redq``, with its
settings in ``app.rl.settings``). Benchmark methods only: the trial service does not offer them
(they need closed-loop control, which a hardware worker does not run).

Nothing is imported here, so ``app.rl.settings`` stays free of MuJoCo and torch."""
