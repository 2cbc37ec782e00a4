"""Instruction counts of the throw's bare physics, weld against friction grasp (load-independent).

CPU times on a shared machine scatter by ±20 %; valgrind's callgrind counts instructions
exactly. This saves the two compiled throw models (reference preset) as MJB files, writes one
held-command episode's commands beside them, compiles a small C loop against the MuJoCo library
bundled with the Python package (``mj_step`` only: no Python, no recording), and runs it under
callgrind for each model. Needs gcc and valgrind.

    nice -n 10 python benchmarks/paper_cost_instructions.py --schedule 0
"""

from __future__ import annotations

import argparse
import re
import subprocess
import tempfile
from pathlib import Path

import mujoco
import numpy as np

from app.policy import Policy
from app.sim import ArmParams, GripperParams, build_model
from app.sim.model import GRIP_WELD

C_LOOP = r"""
#include <stdio.h>
#include <mujoco/mujoco.h>
int main(int argc, char** argv) {
  mjModel* m = mj_loadModel(argv[1], NULL);
  FILE* f = fopen(argv[2], "r");
  int weld, rows;
  if (!m || !f || fscanf(f, "%d %d", &weld, &rows) != 2) return 1;
  mjData* d = mj_makeData(m);
  long nefc = 0;
  for (int r = 0; r < rows; r++) {
    int off;
    if (fscanf(f, "%d", &off) != 1) return 1;
    for (int i = 0; i < m->nu; i++) if (fscanf(f, "%lf", d->ctrl + i) != 1) return 1;
    if (off && weld >= 0) d->eq_active[weld] = 0;
    for (int k = 0; k < 500; k++) { mj_step(m, d); nefc += d->nefc; }
  }
  printf("%ld\n", nefc);
  return 0;
}
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schedule", type=int, default=0, help="which P = 7 random θ (seed 7)")
    args = ap.parse_args()
    policy = Policy(levels=7, with_release=True)
    rng = np.random.default_rng(7)
    decoded = [policy.decode(rng.uniform(size=policy.dim)) for _ in range(args.schedule + 1)]
    d = decoded[args.schedule]
    pkg = Path(mujoco.__file__).parent
    lib = next(pkg.glob("libmujoco.so*"))
    with tempfile.TemporaryDirectory(prefix="paper_cost_") as tmp:
        work = Path(tmp)
        (work / "loop.c").write_text(C_LOOP)
        subprocess.run(
            ["gcc", "-O2", f"-I{pkg / 'include'}", "loop.c", "-o", "loop", str(lib),
             f"-Wl,-rpath,{pkg}"],
            cwd=work, check=True,
        )  # fmt: skip
        counts = {}
        for grasp in ("weld", "friction"):
            model = build_model("throw", "reference", ArmParams(gripper=GripperParams(grasp=grasp)))
            mujoco.mj_saveModel(model, str(work / f"{grasp}.mjb"), None)
            weld = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, GRIP_WELD)
            lines = [f"{weld} {d.pressure_schedule_pa.shape[0]}"]
            for c, row in enumerate(d.pressure_schedule_pa):
                cmd = list(row) + ([1.0 if c < d.release_step else 0.0] if model.nu > 12 else [])
                off = int(model.nu == 12 and c >= d.release_step)
                lines.append(f"{off} " + " ".join(repr(float(x)) for x in cmd))
            (work / f"{grasp}.txt").write_text("\n".join(lines) + "\n")
            run = subprocess.run(
                ["valgrind", "--tool=callgrind", f"--callgrind-out-file={work / grasp}.cg",
                 "./loop", f"{grasp}.mjb", f"{grasp}.txt"],
                cwd=work, check=True, capture_output=True, text=True,
            )  # fmt: skip
            refs = re.search(r"refs:\s+([\d,]+)", run.stderr)
            assert refs is not None, run.stderr
            counts[grasp] = (int(refs.group(1).replace(",", "")), int(run.stdout.split()[0]))
    print(f"schedule {args.schedule} (t_R = {d.release_step}), preset reference, held commands")
    print("| grasp | instructions | constraint rows (sum over steps) | ratio to weld |")
    print("|---|---:|---:|---:|")
    for grasp, (n, rows) in counts.items():
        print(f"| {grasp} | {n:,} | {rows:,} | {n / counts['weld'][0]:.3f} |")


if __name__ == "__main__":
    main()
