"""Command hold, scoring rules and the friction grasp, checked against the published simulator.

The reference data (tests/sim/data/published_reference.json, trimmed from
../shared/fidelity/) are measurements of the simulator published with the paper: the same
schedules run there with commands held ("zoh", our ``command_hold="zero"``) and ramped
("foh", ``"linear"``), scored by its own code with the release time set to the release step
(our ``objective_rule="published"``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from app.sim import RolloutPool, rollout, rollout_batch
from app.sim.rollout import linear_commands, published_throw_steps

DATA = json.loads((Path(__file__).parent / "data" / "published_reference.json").read_text())
HOLD = {"zoh": "zero", "foh": "linear"}


def test_linear_hold_ramps_from_zero_and_reaches_each_row_at_its_steps_end() -> None:
    rows = np.array([[10.0, 0.0], [30.0, 1.0], [30.0, 0.0]])
    per_step = linear_commands(rows, 5)
    assert per_step.shape == (15, 2)
    # step 1 ramps from zeros (reset) to row 1: first physics step repeats the previous command
    np.testing.assert_allclose(per_step[:5, 0], [0.0, 2.5, 5.0, 7.5, 10.0])
    np.testing.assert_allclose(per_step[5:10, 0], [10.0, 15.0, 20.0, 25.0, 30.0])
    np.testing.assert_allclose(per_step[10:, 0], 30.0)
    # a gripper column ramping 1 → 0 is still above zero until the step's last physics step
    np.testing.assert_allclose(per_step[10:, 1], [1.0, 0.75, 0.5, 0.25, 0.0])


@pytest.mark.parametrize(
    ("release", "counted"),
    [(1, []), (2, [1]), (3, [1, 2, 3]), (5, [1, 2, 3, 4, 5]), (9, list(range(1, 10))),
     (10, list(range(1, 10)))],
)  # fmt: skip
def test_published_throw_rule_counts_the_steps_its_float_time_counts(
    release: int, counted: list[int]
) -> None:
    assert published_throw_steps(release, 10).tolist() == counted


def test_unknown_hold_or_rule_is_refused_before_anything_runs() -> None:
    sched = np.full((10, 12), 1e5)
    with pytest.raises(
        ValueError, match="unknown command hold 'cubic'; choose one of zero, linear"
    ):
        rollout("hammer", sched, preset="fast", command_hold="cubic")
    with pytest.raises(ValueError, match="unknown objective rule 'mine'; choose one of paper, "):
        rollout("hammer", sched, preset="fast", objective_rule="mine")
    with pytest.raises(ValueError, match="unknown command hold"):
        rollout_batch("hammer", [sched, sched], n_workers=2, command_hold="ramp")
    with pytest.raises(ValueError, match="unknown objective rule"):
        RolloutPool("hammer", preset="fast", n_workers=1, objective_rule=None)  # type: ignore[arg-type]


def test_hold_and_rule_change_the_result_and_it_says_which() -> None:
    case = next(c for c in DATA["modes"]["foh"] if c["task"] == "hammer")
    sched = np.array(case["pressures_pa"])
    zero = rollout("hammer", sched, preset="fast")
    linear = rollout("hammer", sched, preset="fast", command_hold="linear")
    published = rollout("hammer", sched, preset="fast", objective_rule="published")
    assert (zero.command_hold, zero.objective_rule) == ("zero", "paper")
    summary = published.to_summary()
    assert (summary["command_hold"], summary["objective_rule"]) == ("zero", "published")
    assert published.objective == summary["objective_by_rule"]["published"]
    assert published.objective != zero.objective
    assert zero.objective_by_rule == published.objective_by_rule  # same episode, both rules
    # ramped from zero, the pressure states lag the held commands' from the first step on
    p_zero, p_lin = zero.trajectory.pressure_pa, linear.trajectory.pressure_pa
    assert np.all(p_lin[1:50].sum(axis=1) < p_zero[1:50].sum(axis=1))
    assert np.abs(linear.tip_speed_100hz - zero.tip_speed_100hz).max() > 0.1


def test_batch_and_pool_pass_the_hold_and_rule_on() -> None:
    case = next(c for c in DATA["modes"]["foh"] if c["task"] == "throw")
    sched, rel = np.array(case["pressures_pa"]), case["release_step"]
    one = rollout(
        "throw", sched, release_step=rel, preset="fast", command_hold="linear",
        objective_rule="published",
    )  # fmt: skip
    batch = rollout_batch(
        "throw", [sched, sched], release_steps=[rel, rel], preset="fast", n_workers=2,
        command_hold="linear", objective_rule="published",
    )  # fmt: skip
    for res in batch:
        assert (res.command_hold, res.objective_rule) == ("linear", "published")
        assert res.objective == one.objective


@dataclass
class Compared:
    case: dict
    max_rel: float
    corr: float
    j_rel: float
    lost: bool | None
    last_contact_s: float | None


def compare(mode: str, preset: str) -> list[Compared]:
    out = []
    cases = DATA["modes"][mode]
    for task in ("throw", "hammer"):
        mine = [c for c in cases if c["task"] == task]
        results = rollout_batch(
            task,
            [np.array(c["pressures_pa"]) for c in mine],
            release_steps=[c["release_step"] for c in mine] if task == "throw" else None,
            preset=preset,
            command_hold=HOLD[mode],
            objective_rule="published",
        )
        for c, r in zip(mine, results, strict=True):
            ref = np.array(c["tip_speed_100hz"])
            out.append(
                Compared(
                    case=c,
                    max_rel=r.max_tip_speed / c["max_tip_speed"] - 1.0,
                    corr=float(np.corrcoef(ref, r.tip_speed_100hz)[0, 1]),
                    j_rel=r.objective / c["J"] - 1.0,
                    lost=r.cube_lost_before_release,
                    last_contact_s=r.last_pad_contact_s,
                )
            )
    return out


def share(flags: list[bool]) -> float:
    return sum(flags) / len(flags)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["zoh", "foh"])
def test_reference_preset_matches_the_published_simulator(mode: str) -> None:
    rows = compare(mode, "reference")
    hammer = [r for r in rows if r.case["task"] == "hammer"]
    throw = [r for r in rows if r.case["task"] == "throw"]
    # hammer: every case, the tolerances (J under the published rule)
    for r in hammer:
        assert abs(r.max_rel) <= 0.03 and r.corr >= 0.95, r.case["id"]
        assert abs(r.j_rel) <= 0.05 or abs(r.j_rel * r.case["J"]) < 1e-3, r.case["id"]
    # throw with the friction grasp: the slip verdict agrees on ≥ 80 % of the throws ...
    assert share([r.lost == r.case["cube_lost_before_release"] for r in throw]) >= 0.8
    # ... and where neither simulator lost the cube, the traces and J match
    held = [r for r in throw if not r.lost and not r.case["cube_lost_before_release"]]
    assert len(held) >= 0.5 * len(throw)
    assert share([abs(r.max_rel) <= 0.03 for r in held]) == 1.0
    # the 0.95 and 5 % on every one, held and ramped (worst 0.971 and 4 %): since the
    # fingers' and the cube's contacts carry the published linkage's give, the impacts that
    # put held case 3's J 22 % low and ramped case 5's correlation at 0.941 match:
    # docs/bench/paper.md (a″)
    assert share([r.corr >= 0.95 for r in held]) == 1.0
    assert share([abs(r.j_rel) <= 0.05 for r in held]) == 1.0
    # and the pads let go when the published gripper does (release command + latency; the
    # ramped mode opens 0.5 s later than the held one, so 0.15 s tells them apart)
    for r in held:
        ref_last = r.case["last_pad_contact_time_s"]
        if ref_last < 0.5 * r.case["release_step"] + 0.1:
            assert r.last_contact_s == pytest.approx(ref_last, abs=0.15), r.case["id"]


@pytest.mark.parametrize("mode", ["zoh", "foh"])
def test_fast_preset_stays_near_the_published_simulator(mode: str) -> None:
    """The issue's ``fast`` target on every case, throws and hammer: max tip speed within 10 %,
    trace correlation ≥ 0.9 (worst +5.6 % and 0.976). Revision 1 missed it on three throws:
    joints bent past where their disks meet (held case 17 +13 %, ramped case 1 +11 %) and the
    welded cube's fingers passed through the floor (held case 0, 0.873)."""
    rows = compare(mode, "fast")  # the fast preset welds the cube
    assert [r.case["id"] for r in rows if abs(r.max_rel) > 0.10] == []
    assert [r.case["id"] for r in rows if r.corr < 0.9] == []
    old = compare(mode, "fast-r1")  # the same check tells the revisions apart
    assert [r.case["id"] for r in old if abs(r.max_rel) > 0.10 or r.corr < 0.9] == (
        [0, 17] if mode == "zoh" else [1]
    )


OPTIMISED = json.loads(
    (Path(__file__).parent / "data" / "published_optimised_throws.json").read_text()
)


def test_fast_weld_scores_the_optimisers_best_throws_as_the_published_simulator_does() -> None:
    """The sweep's 110 best throws (fast, ramped, published rule), run through the published
    simulator: every one loses the cube before its release step there, yet ``fast``'s weld,
    which never does, scores them as closely as the reference friction grasp that loses all
    110 (docs/bench/paper.md (f): mean |ΔJ| 1.14 against 1.26, correlation 0.969 against
    0.973). This is where the weld earns its place in the paper-matching preset."""
    cases = OPTIMISED["cases"]
    assert len(cases) == 110 and all(c["cube_lost_before_release"] for c in cases)
    results = rollout_batch(
        "throw",
        [np.asarray(c["pressures_pa"]) for c in cases],
        release_steps=[c["release_step"] for c in cases],
        preset="fast",
        n_workers=1,
        command_hold="linear",
        objective_rule="published",
    )
    j = np.array([r.objective for r in results])
    j_pub = np.array([c["J_published"] for c in cases])
    assert not any(r.cube_lost_before_release for r in results)  # the weld holds on
    assert np.abs(j - j_pub).mean() < 1.4
    assert abs(np.mean(j - j_pub)) < 0.6
    assert np.corrcoef(j, j_pub)[0, 1] > 0.95


HAMMERS = json.loads(
    (Path(__file__).parent / "data" / "published_optimised_hammers.json").read_text()
)


def _best_hammers(preset: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """J in ``preset`` now, J its sweep stored and J published of that preset's best hammers."""
    cases = [c for c in HAMMERS["cases"] if c["sweep_preset"] == preset]
    results = rollout_batch(
        "hammer",
        [np.asarray(c["pressures_pa"]) for c in cases],
        preset=preset,
        n_workers=1,
        command_hold="linear",
        objective_rule="published",
    )
    j = np.array([r.objective for r in results])
    return j, np.array([c["J_sweep"] for c in cases]), np.array([c["J_published"] for c in cases])


@pytest.mark.slow
def test_fast_revision_2_scores_the_optimisers_best_hammers_nearer_the_published_simulator() -> (
    None
):
    """The sweep's best hammer schedules (ramped, published rule), run through the published
    simulator: revision 1 of ``fast`` had scored them 1.6 too high on average (correlation 0.20:
    its best strikes landed on the control-step ends whose plate reading counts, the published
    arm's do not); revision 2, 0.49 too high, correlation 0.67 (docs/bench/paper.md (e⁵)).
    Revision 2 also still reproduces what its sweep stored, so the cached runs stand for
    today's physics."""
    j, j_sweep, j_pub = _best_hammers("fast")
    np.testing.assert_allclose(j, j_sweep, rtol=1e-9)
    assert np.abs(j - j_pub).mean() < 0.75
    assert np.corrcoef(j, j_pub)[0, 1] > 0.55
    j, _, j_pub = _best_hammers("fast-r1")
    assert np.abs(j - j_pub).mean() > 1.2
    assert np.corrcoef(j, j_pub)[0, 1] < 0.4
