"""REDQ (Chen et al., 2021), the paper's model-free RL baseline, from Tianshou: its ``REDQ``
algorithm, ``REDQPolicy``, ensemble critic (``EnsembleLinear``) and ``ReplayBuffer``.
handful adds only the loop the sweep needs: one episode = one trial.

    agent = REDQAgent(HandfulEnv("hammer"), REDQSettings(), seed=0)
    ep = agent.run_episode()      # ep.objective: the simulator's objective of that episode

Episodes 1..``pretrain_episodes`` command uniformly random pressures (and release) and do not
learn: the paper's 2,500 transitions of pre-training data, counted as trials. From then on the
policy acts (sampling, as REDQ explores) and after each transition the agent makes ``utd``
gradient updates (critics every update, the policy and entropy temperature every ``utd``-th,
REDQ's delayed policy update).

Why Tianshou (measured, docs/bench/redq.md): with the paper's sizes it costs 0.37× TorchRL's
REDQLoss per update, within 10 % of a bare PyTorch critic update, and its REDQ is the whole
algorithm (policy delay, ensemble subset, auto-α) rather than a loss to assemble.

Randomness: the run's seed sets torch's and NumPy's global generators (Tianshou draws ensemble
subsets from NumPy's global one), the replay buffer's batch sampler and this agent's own
generator; a checkpoint holds all four, so a resumed run continues exactly where it stopped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tianshou.algorithm import REDQ
from tianshou.algorithm.modelfree.redq import REDQPolicy
from tianshou.algorithm.modelfree.sac import AutoAlpha
from tianshou.algorithm.optim import AdamOptimizerFactory
from tianshou.data import Batch, ReplayBuffer
from tianshou.utils.net.common import EnsembleLinear, Net
from tianshou.utils.net.continuous import ContinuousActorProbabilistic, ContinuousCritic
from tianshou.utils.torch_utils import policy_within_training_step

from app.rl.env import HandfulEnv
from app.rl.settings import REDQSettings

BUFFER_SIZE = 200_000  # transitions kept (20,000 episodes: every transition of a 10K run)


@dataclass
class EpisodeResult:
    """One trial: the simulator's objective (NaN if the physics diverged), the commands (H, n)
    as fractions of the maximum (plus the release entry for throwing), the return, timing."""

    objective: float
    actions: np.ndarray
    episode_return: float
    release_step: int | None
    sim_s: float
    learn_s: float
    random: bool


class REDQAgent:
    """Tianshou's REDQ acting in and learning from a ``HandfulEnv`` (module docstring)."""

    def __init__(self, env: HandfulEnv, settings: REDQSettings, seed: int = 0) -> None:
        self.env, self.settings, self.seed = env, settings.checked(), int(seed)
        torch.manual_seed(self.seed)
        np.random.seed(self.seed % 2**32)  # Tianshou's batches and ensemble subsets
        self.rng = np.random.default_rng(self.seed)
        s = self.settings
        obs_dim = int(np.prod(env.observation_space.shape))
        act_dim = int(np.prod(env.action_space.shape))
        device = torch.device(s.device)

        def ensemble_linear(n_in: int, n_out: int) -> EnsembleLinear:
            return EnsembleLinear(s.ensemble_size, n_in, n_out)

        actor = ContinuousActorProbabilistic(
            preprocess_net=Net(state_shape=obs_dim, hidden_sizes=s.hidden_sizes),
            action_shape=act_dim,
            unbounded=True,
            conditioned_sigma=True,
        ).to(device)
        critic = ContinuousCritic(
            preprocess_net=Net(
                state_shape=obs_dim,
                action_shape=act_dim,
                hidden_sizes=s.hidden_sizes,
                concat=True,
                linear_layer=ensemble_linear,
            ),
            linear_layer=ensemble_linear,
            flatten_input=False,
        ).to(device)
        self.policy = REDQPolicy(
            actor=actor,
            action_space=env.action_space,
            observation_space=env.observation_space,
        )
        self.algorithm = REDQ(
            policy=self.policy,
            policy_optim=AdamOptimizerFactory(lr=s.lr),
            critic=critic,
            critic_optim=AdamOptimizerFactory(lr=s.lr),
            ensemble_size=s.ensemble_size,
            subset_size=s.subset_size,
            tau=s.tau,
            gamma=s.gamma,
            alpha=AutoAlpha(-float(act_dim), 0.0, AdamOptimizerFactory(lr=s.lr)),
            actor_delay=s.utd,
        )
        self.buffer = ReplayBuffer(BUFFER_SIZE, random_seed=self.seed)  # samples its batches
        self.episodes = 0
        self.act_dim = act_dim

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """An action in the policy's [-1, 1] box: uniform while pre-training, else sampled."""
        if self.episodes < self.settings.pretrain_episodes:
            return self.rng.uniform(-1.0, 1.0, self.act_dim).astype(np.float32)
        with torch.no_grad(), policy_within_training_step(self.policy):
            out = self.policy(Batch(obs=obs[None], info=Batch()))
        return out.act[0].cpu().numpy().astype(np.float32)

    def run_episode(self) -> EpisodeResult:
        """One episode (a trial), learning after each transition once pre-training is over."""
        env, s = self.env, self.settings
        random = self.episodes < s.pretrain_episodes
        sim_s = learn_s = 0.0
        obs, _ = env.reset()
        actions, total, info = [], 0.0, {}
        done = False
        while not done:
            act = self._act(obs)
            env_act = self.policy.map_action(act)
            t1 = time.perf_counter()
            obs_next, reward, terminated, truncated, info = env.step(env_act)
            sim_s += time.perf_counter() - t1
            done = terminated or truncated
            self.buffer.add(
                Batch(
                    obs=obs,
                    act=act,
                    rew=reward,
                    terminated=terminated,
                    truncated=truncated,
                    obs_next=obs_next,
                    info={},
                )
            )
            actions.append(np.clip(env_act, 0.0, 1.0))
            total += reward
            obs = obs_next
            if not random:
                t2 = time.perf_counter()
                self.learn(s.utd)
                learn_s += time.perf_counter() - t2
        self.episodes += 1
        return EpisodeResult(
            objective=float(info.get("objective", float("nan"))),
            actions=np.array(actions),
            episode_return=total,
            release_step=info.get("release_step"),
            sim_s=sim_s,
            learn_s=learn_s,
            random=random,
        )

    def learn(self, updates: int) -> None:
        """``updates`` gradient steps of REDQ on batches from the replay buffer."""
        with policy_within_training_step(self.policy):
            for _ in range(updates):
                self.algorithm.update(buffer=self.buffer, sample_size=self.settings.batch_size)

    # --- checkpoints: the whole agent, so a resumed run continues exactly -------------------

    def state(self) -> dict[str, Any]:
        """Everything a resumed run needs: weights, optimisers, buffer, generators."""
        return {
            "episodes": self.episodes,
            "algorithm": self.algorithm.state_dict(),
            "optims": [o.state_dict() for o in self._optims()],
            "buffer": self._compact_buffer(),
            "rng": self.rng.bit_generator.state,
            "np_global": np.random.get_state(),
            "torch": torch.get_rng_state(),
            "critic_steps": self.algorithm.critic_gradient_step,
        }

    def load(self, state: dict[str, Any]) -> None:
        """Continue from ``state`` (``state()`` of an agent built with the same settings)."""
        self.episodes = int(state["episodes"])
        self.algorithm.load_state_dict(state["algorithm"])
        for o, sd in zip(self._optims(), state["optims"], strict=True):
            o.load_state_dict(sd)
        self.buffer = ReplayBuffer(BUFFER_SIZE)
        self.buffer.update(state["buffer"])  # same slots as before: never wrapped below 200K
        self.buffer._random_state = state["buffer"]._random_state  # where its sampling was
        self.rng.bit_generator.state = state["rng"]
        np.random.set_state(state["np_global"])
        torch.set_rng_state(state["torch"].cpu())
        self.algorithm.critic_gradient_step = int(state["critic_steps"])

    def _compact_buffer(self) -> ReplayBuffer:
        """The stored transitions in a buffer just their size (the live one is preallocated)."""
        small = ReplayBuffer(max(1, len(self.buffer)))
        small.update(self.buffer)
        small._random_state = self.buffer._random_state  # the batch sampler's generator
        return small

    def _optims(self) -> list[torch.optim.Optimizer]:
        """Optimisers outside the algorithm's state_dict (which holds the policy's and critics'):
        the entropy temperature's."""
        alpha_optim = getattr(self.algorithm.alpha, "_optim", None)
        return [alpha_optim] if alpha_optim is not None else []

    def save(self, path: Path) -> None:
        """Write ``state()`` to ``path`` atomically."""
        tmp = Path(path).with_suffix(".tmp")
        torch.save(self.state(), tmp)
        tmp.replace(path)

    def restore(self, path: Path) -> None:
        """``load`` a checkpoint written by ``save``."""
        self.load(torch.load(path, weights_only=False, map_location=self.settings.device))
