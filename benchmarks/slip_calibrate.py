"""Choose the weld-slip grasp's two settings against the published simulator's throws.

Cases: the published reference throws (../shared/fidelity, 12 held + 6 ramped, copied in
tests/sim/data) and the sweep's optimised throws run through the published simulator
(tests/sim/data/published_optimised_throws.json, ramped: what the optimisers actually hand
over, where fast swings lose the cube). For each (``slip_hold_n``, ``slip_out_m``) on the grid
it runs every case in ``--preset`` with the grasp ``weld-slip`` and prints, beside the weld's
own row: slip verdicts that agree with the published simulator's, the mean and median |ΔJ|
(published rule) and the per-θ correlation of J on the optimised throws.

    nice -n 10 python benchmarks/slip_calibrate.py --hold-n 6 8 12 16 --out-m 0.034 0.1 \
        --with-reference
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
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


def score(cases: list[dict], preset: Preset, params: ArmParams | None = None) -> dict:
    """Run every case in ``preset`` (``params``); agreement with the published sim, per group."""
    out: dict = {}
    t0 = time.process_time()
    for c in cases:
        r = rollout(
            "throw",
            np.asarray(c["pressures_pa"]),
            release_step=c["release_step"],
            preset=preset,
            params=params,
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
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--hold-n", type=float, nargs="+", default=[6.0, 8.0, 12.0, 16.0])
    ap.add_argument("--out-m", type=float, nargs="+", default=[0.034, 0.1])
    ap.add_argument(
        "--with-reference", action="store_true", help="add the reference preset's friction grasp"
    )
    args = ap.parse_args()
    cases = load_cases()
    base = get_preset(args.preset)
    print(
        f"*{len(cases)} published throws; preset {args.preset} (physics), scoring rule "
        "published; each group's slip verdicts that agree, and |ΔJ| mean / median*\n"
    )
    print(
        "| grasp | held: verdicts | held: abs ΔJ | ramped: verdicts | ramped: abs ΔJ | "
        "optimised: verdicts | optimised: abs ΔJ | optimised: mean ΔJ | optimised: J corr | "
        "CPU s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    weld = replace(base, name=f"{base.name}-weld", grasp="weld")
    print(row("weld", score(cases, weld)), flush=True)
    if args.with_reference:
        print(row("friction (reference preset)", score(cases, get_preset("reference"))), flush=True)
    for hold_n in args.hold_n:
        for out_m in args.out_m:
            p = replace(base, name=f"{base.name}-slip", grasp="weld-slip")
            arm = ArmParams()
            gp = replace(arm.gripper, slip_hold_n=hold_n, slip_out_m=out_m)
            res = score(cases, p, replace(arm, gripper=gp))
            print(row(f"weld-slip {hold_n:g} N, {out_m:g} m", res), flush=True)


if __name__ == "__main__":
    main()
