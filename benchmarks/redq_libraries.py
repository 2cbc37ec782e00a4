"""Tianshou's REDQ vs TorchRL's REDQLoss vs a bare PyTorch critic update: seconds per gradient
update with the paper's sizes (obs 6, action 12, two layers of 256, 2 critics, batch 256), one
torch thread, 2,500 random transitions in the buffer.

    python benchmarks/redq_libraries.py tianshou|torchrl|torch

Each library runs in its own process (TorchRL is not a handful dependency: install it beside
torch==2.13.0, e.g. ``pip install --target DIR torchrl==0.14.1 tensordict==0.14.3 --no-deps``
plus its small deps, and put DIR on PYTHONPATH). Compare numbers taken back to back.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch
from torch import nn

OBS, ACT, N, BATCH = 6, 12, 2500, 256


def per_update(step, n: int = 160, warm: int = 20) -> float:
    for _ in range(warm):
        step()
    t0 = time.perf_counter()
    for _ in range(n):
        step()
    return (time.perf_counter() - t0) / n


def bare_torch() -> float:
    def mlp(i: int, o: int) -> nn.Module:
        return nn.Sequential(
            nn.Linear(i, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, o)
        )

    q1, q2, pi = mlp(OBS + ACT, 1), mlp(OBS + ACT, 1), mlp(OBS, 2 * ACT)
    opt = torch.optim.Adam([*q1.parameters(), *q2.parameters()], 3e-4)
    x, s = torch.randn(BATCH, OBS + ACT), torch.randn(BATCH, OBS)

    def step() -> None:
        with torch.no_grad():
            pi(s)
            target = torch.min(q1(x), q2(x))
        loss = ((q1(x) - target) ** 2).mean() + ((q2(x) - target) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    return per_update(step)


def tianshou() -> float:
    import gymnasium as gym

    from app.rl.env import HandfulEnv
    from app.rl.redq import REDQAgent
    from app.rl.settings import REDQSettings

    del gym
    agent = REDQAgent(HandfulEnv("hammer", preset="fast"), REDQSettings(), seed=0)
    rng = np.random.default_rng(0)
    from tianshou.data import Batch

    for t in range(N):
        agent.buffer.add(
            Batch(
                obs=rng.normal(size=OBS).astype(np.float32),
                act=rng.uniform(-1, 1, ACT).astype(np.float32),
                rew=float(rng.normal()),
                terminated=t % 10 == 9,
                truncated=False,
                obs_next=rng.normal(size=OBS).astype(np.float32),
                info={},
            )
        )
    return per_update(lambda: agent.learn(1))


def torchrl() -> float:
    from tensordict import TensorDict
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torchrl.data import Bounded, LazyTensorStorage, ReplayBuffer
    from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import REDQLoss, SoftUpdate

    net = nn.Sequential(
        MLP(in_features=OBS, out_features=2 * ACT, num_cells=[256, 256]), NormalParamExtractor()
    )
    actor = ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        return_log_prob=True,
    )

    class Q(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.m = MLP(in_features=OBS + ACT, out_features=1, num_cells=[256, 256])

        def forward(self, o: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
            return self.m(torch.cat([o, a], -1))

    qnet = ValueOperator(Q(), in_keys=["observation", "action"])
    td = TensorDict({"observation": torch.randn(4, OBS)}, [4])
    actor(td)
    qnet(td)
    loss = REDQLoss(
        actor_network=actor,
        qvalue_network=qnet,
        num_qvalue_nets=2,
        sub_sample_len=2,
        action_spec=Bounded(-1.0, 1.0, (ACT,)),
    )
    loss.make_value_estimator(gamma=0.99)
    upd = SoftUpdate(loss, eps=0.995)
    opt = torch.optim.Adam(loss.parameters(), 3e-4)
    nxt = {
        "observation": torch.randn(N, OBS),
        "reward": torch.randn(N, 1),
        "done": torch.zeros(N, 1, dtype=torch.bool),
        "terminated": torch.zeros(N, 1, dtype=torch.bool),
    }
    data = TensorDict(
        {
            "observation": torch.randn(N, OBS),
            "action": torch.rand(N, ACT) * 2 - 1,
            "next": TensorDict(nxt, [N]),
        },
        [N],
    )
    rb = ReplayBuffer(storage=LazyTensorStorage(100_000), batch_size=BATCH)
    rb.extend(data)

    def step() -> None:
        out = loss(rb.sample())
        total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
        opt.zero_grad()
        total.backward()
        opt.step()
        upd.step()

    return per_update(step)


if __name__ == "__main__":
    torch.set_num_threads(1)
    which = sys.argv[1] if len(sys.argv) > 1 else "tianshou"
    fn = {"tianshou": tianshou, "torchrl": torchrl, "torch": bare_torch}[which]
    print(f"{which}: {1e3 * fn():.1f} ms per update")
