"""Each throw grasp against the published simulator, on its reference throws and on optimised ones.

Cases: the published reference throws (../shared/fidelity, 12 held + 6 ramped, copied in
tests/sim/data) and the optimiser sweep's best throws run through the published simulator
(tests/sim/data/published_optimised_throws.json, ramped: what the optimisers actually hand
over, where fast swings lose the cube). Each case runs in each (preset, its own grasp): the weld
of ``fast`` and the friction grasp of ``reference``. Printed per row: the slip verdicts that
agree with the published simulator's, the mean and median |ΔJ| (published rule), and on the
optimised throws the mean ΔJ and the per-θ correlation of J; CPU seconds for the row.

    nice -n 10 python benchmarks/grasp_vs_published.py --presets fast reference

(Session 13 also calibrated a ``weld-slip`` grasp with this script's forerunner,
``benchmarks/slip_calibrate.py`` at commit e96ce26; its table is
docs/bench/paper/slip_calibrate_session13.md.)
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from app.sim import ArmParams, Preset, rollout
from app.sim.presets import get_preset

ROOT = Path(__file__).resolve().parents[1]
OPTIMISED = ROOT / "tests" / "sim" / "data" / "published_optimised_throws.json"
REFERENCE = ROOT / "tests" / "sim" / "data" / "published_reference.json"
HOLDS = {"zoh": "zero", "foh": "linear"}


def load_cases() -> list[dict]:
    """Every throw case: schedule (10, 12) Pa, release step, hold, published J / lost / D."""
    cases = []
    modes = json.loads(REFERENCE.read_text())["modes"]
    for mode, hold in HOLDS.items():
        for c in modes[mode]:
            if c["task"] == "throw":
                cases.append(
                    {
                        "id": f"ref-{hold}-{c['id']}",
                        "group": f"reference, {hold}",
                        "pressures_pa": c["pressures_pa"],
                        "release_step": c["release_step"],
                        "hold": hold,
                        "J": c["J"],
                        "lost": c["cube_lost_before_release"],
                        "D_cube": c["D_cube"],
                    }
                )
    for c in json.loads(OPTIMISED.read_text())["cases"]:
        cases.append(
            {
                "id": c["id"],
                "group": "optimised, linear",
                "pressures_pa": c["pressures_pa"],
                "release_step": c["release_step"],
                "hold": "linear",
                "J": c["J_published"],
                "lost": c["cube_lost_before_release"],
                "D_cube": c["D_cube"],
            }
        )
    return cases


def score(cases: list[dict], preset: Preset) -> dict:
    """Run every case in ``preset``; agreement with the published simulator, per group."""
    out: dict = {}
    t0 = time.process_time()
    for c in cases:
        r = rollout(
            "throw",
            np.asarray(c["pressures_pa"]),
            release_step=c["release_step"],
            preset=preset,
            command_hold=c["hold"],
            objective_rule="published",
        )
        g = out.setdefault(c["group"], {"agree": 0, "n": 0, "dj": [], "j": [], "jp": []})
        g["n"] += 1
        g["agree"] += bool(r.cube_lost_before_release) == bool(c["lost"])
        g["dj"].append(r.objective - c["J"])
        g["j"].append(r.objective)
        g["jp"].append(c["J"])
    return {"groups": out, "cpu_s": time.process_time() - t0}


def row(label: str, res: dict) -> str:
    cells = [label]
    for name in ("reference, zero", "reference, linear", "optimised, linear"):
        g = res["groups"][name]
        dj = np.abs(g["dj"])
        cells.append(f"{g['agree']} / {g['n']}")
        cells.append(f"{dj.mean():.2f} / {np.median(dj):.2f}")
    g = res["groups"]["optimised, linear"]
    cells.append(f"{np.mean(g['dj']):+.2f}")
    cells.append(f"{np.corrcoef(g['j'], g['jp'])[0, 1]:.3f}")
    cells.append(f"{res['cpu_s']:.0f}")
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["fast", "reference"])
    args = ap.parse_args()
    cases = load_cases()
    print(
        f"*{len(cases)} published throws, scoring rule published; each group's slip verdicts "
        "that agree, and |ΔJ| mean / median*\n"
    )
    print(
        "| preset (grasp) | held: verdicts | held: abs ΔJ | ramped: verdicts | ramped: abs ΔJ | "
        "optimised: verdicts | optimised: abs ΔJ | optimised: mean ΔJ | optimised: J corr | "
        "CPU s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in args.presets:
        preset = get_preset(name)
        grasp = preset.grasp or ArmParams().gripper.grasp
        print(row(f"{name} ({grasp})", score(cases, preset)), flush=True)


if __name__ == "__main__":
    main()
