"""REDQ in the sweep: settings checks, rows, exact resume from checkpoints, backends, and the
trial service refusing it."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from app import bench
from app.bench.cache import read_run, run_dir
from app.optim import METHODS, SettingsError
from app.rl.settings import REDQSettings

HANDFUL = shutil.which("handful") or str(Path(sys.executable).with_name("handful"))


def handful(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [HANDFUL, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=env
    )


# tiny networks and few pre-training episodes: learning starts at episode 3
TINY = {"pretrain_episodes": 2, "batch_size": 8, "utd": 2, "hidden_sizes": [16, 16]}


def spec(budget: int, method: str = "redq", **settings) -> bench.RunSpec:
    return bench.RunSpec(
        method,
        "hammer",
        bench.RL_LEVELS,
        0,
        budget,
        "fast",
        settings={**TINY, "checkpoint_every": 2, **settings},
        command_hold="linear",
        objective_rule="published",
    )


def objectives(rows: list[dict]) -> list[float]:
    return [r["objective"] for r in rows]


def test_paper_settings_are_the_defaults_and_bad_ones_get_one_line() -> None:
    s = REDQSettings.for_method("redq-joints")
    assert (s.hidden_sizes, s.ensemble_size, s.utd, s.pretrain_episodes) == ((256, 256), 2, 16, 250)
    assert s.observations == "joints" and REDQSettings.for_method("redq").observations == "task"
    for settings, words in (
        ({"utd": 0}, "utd (gradient updates per environment transition) must be"),
        ({"utd": -3}, "got -3"),
        ({"observations": "pixels"}, "unknown observation set 'pixels'"),
        ({"observations": "joints"}, "redq observes 'task'"),
        ({"subset_size": 3}, "subset_size (3) must be ≤ ensemble_size (2)"),
        ({"colour": 1}, "unknown REDQ setting 'colour'"),
    ):
        with pytest.raises(SettingsError, match=None) as info:
            bench.make_specs(
                methods=["redq"], tasks=["hammer"], levels=[2], budgets=[5], seeds=1,
                preset="fast", rl_settings=settings,
            )  # fmt: skip
        assert words in str(info.value) and "\n" not in str(info.value)


def test_rl_methods_are_sweep_methods_not_service_optimisers() -> None:
    assert "redq" not in METHODS and "redq-joints" not in METHODS
    assert {"redq", "redq-joints"} <= set(bench.SWEEP_METHODS)
    specs = bench.make_specs(
        methods=["redq", "random"], tasks=["hammer"], levels=[2, 5], budgets=[5], seeds=2,
        preset="fast",
    )  # fmt: skip
    # one REDQ run per (task, seed), whatever the P values: it needs no P
    assert sorted((s.method, s.levels, s.seed) for s in specs if s.is_rl) == [
        ("redq", 0, 0),
        ("redq", 0, 1),
    ]
    assert len([s for s in specs if not s.is_rl]) == 4


@pytest.mark.slow
def test_a_run_writes_a_row_per_episode_and_resumes_exactly_from_its_checkpoint(
    tmp_path: Path,
) -> None:
    whole = bench.run_one(spec(6), tmp_path / "whole")
    assert [r["trial"] for r in whole] == list(range(1, 7))
    assert all(math.isfinite(v) and v != 0 for v in objectives(whole))
    assert all(len(r["theta"]) == 10 * 12 for r in whole)  # the episode's commands
    assert all(0.0 <= v <= 1.0 for r in whole for v in r["theta"])
    # the same run cut at 4 episodes, then asked for 6: it continues from the checkpoint
    out = tmp_path / "cut"
    first = bench.run_one(spec(4), out)
    assert objectives(first) == objectives(whole)[:4]
    assert (run_dir(out) / f"{spec(4).key}.agent.pt").exists()
    resumed = bench.run_one(spec(6), out)
    assert objectives(resumed) == objectives(whole)
    # interrupted after episode 5: rows beyond the last checkpoint (4) are dropped and rerun
    out2 = tmp_path / "interrupted"
    bench.run_one(spec(6), out2)
    final = run_dir(out2) / f"{spec(6).key}.csv"
    part = final.with_name(f"{spec(6).key}.part.csv")
    lines = final.read_text().splitlines()
    bad = lines[5].split(",", 2)
    part.write_text("\n".join([*lines[:5], f"{bad[0]},123.0,{bad[2]}"]) + "\n")
    final.unlink()
    ckpt = run_dir(out2) / f"{spec(6).key}.agent.pt"
    bench.run_one(spec(4), tmp_path / "ck")  # a checkpoint at episode 4
    ckpt.write_bytes((run_dir(tmp_path / "ck") / f"{spec(4).key}.agent.pt").read_bytes())
    again = bench.run_one(spec(6), out2)
    assert objectives(again) == objectives(whole) and 123.0 not in objectives(again)
    # no checkpoint: the run starts over rather than mixing two agents' rows
    ckpt.unlink()
    bench.write_part(part, [{**r, "objective": -1.0} for r in whole[:3]])
    final.unlink()
    assert objectives(bench.run_one(spec(6), out2)) == objectives(whole)
    assert objectives(read_run(final)) == objectives(whole)


@pytest.mark.slow
def test_redq_joints_on_local_and_ray_backends_agree(tmp_path: Path, sweep_both_ways) -> None:
    specs = bench.make_specs(
        methods=["redq-joints"], tasks=["throw"], levels=[2], budgets=[4], seeds=2,
        preset="fast", command_hold="linear", objective_rule="published", rl_settings=TINY,
    )  # fmt: skip
    local, remote = sweep_both_ways(specs, workers=1)
    for s in specs:
        assert objectives(remote[s]) == objectives(local[s])
        assert len(local[s]) == 4 and len(local[s][0]["theta"]) == 10 * 13
    rows = bench.write_outputs(tmp_path / "local", specs, local, [4])
    assert {r["method"] for r in rows} == {"redq-joints"} and {r["levels"] for r in rows} == {0}
    best = [r["best_so_far"] for r in rows if r["seed"] == 0]
    assert best == sorted(best) and best[-1] == max(objectives(local[specs[0]]))


def test_cli_refuses_bad_redq_settings_with_one_line(tmp_path: Path) -> None:
    for args, message in (
        (["--redq", "utd=0"], "REDQ utd (gradient updates per environment transition)"),
        (["--redq", "observations=pixels"], "unknown observation set 'pixels'"),
        (["--redq", "utd"], "--redq takes KEY=VALUE"),
    ):
        res = handful(
            "bench", "optim", "--methods", "redq", "--task", "hammer", *args,
            "--out", str(tmp_path / "o"), cwd=tmp_path,
        )  # fmt: skip
        assert res.returncode == 2, (args, res.stderr)
        assert message in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert not (tmp_path / "o").exists()
    # a setting right for the method asked for is not checked against the other RL method
    res = handful(
        "bench", "optim", "--methods", "redq", "--task", "hammer", "--redq", "observations=task",
        "--cached-only", "--out", str(tmp_path / "o"), cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 2 and "no runs of this sweep stored" in res.stderr, res.stderr


def test_the_trial_service_refuses_redq(api) -> None:
    from app.client import HandfulAPIError

    for method in ("redq", "redq-joints"):
        with pytest.raises(HandfulAPIError) as info:
            api.create_experiment(name="rl", task="hammer", levels=3, method=method)
        assert info.value.status == 422
        detail = json.dumps(info.value.detail)
        assert method in detail and "bo-lei" in detail  # names the methods it does offer
        assert "redq" not in detail.replace(f"'{method}'", "")


def test_pretraining_episodes_are_the_same_for_both_observation_sets() -> None:
    # uniformly random commands from the run's seed: what the agent observes changes nothing
    # until it learns (so the 250-trial cells of redq and redq-joints agree seed by seed)
    a = bench.run_one(spec(2), None)
    b = bench.run_one(spec(2, "redq-joints"), None)
    assert objectives(a) == objectives(b) and [r["theta"] for r in a] == [r["theta"] for r in b]
    c = bench.run_one(bench.RunSpec(**{**spec(2).__dict__, "seed": 1}), None)
    assert objectives(c) != objectives(a)
