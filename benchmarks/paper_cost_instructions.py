"""Instruction counts of the throw's bare physics, weld against friction grasp (load-independent).

CPU times on a shared machine scatter by ±20 %; valgrind's callgrind counts instructions
exactly. This saves the two compiled throw models (reference preset) as MJB files, writes one
held-command episode's commands beside them, compiles a small C loop against the MuJoCo library
bundled with the Python package (``mj_step`` only: no Python, no recording), and runs it under
callgrind for each model. Needs gcc and valgrind.

    nice -n 10 python benchmarks/paper_cost_instructions.py --schedule 0 [--hybrid]

``--hybrid`` adds a third model, a cost probe (not a grasp handful offers): the friction grasp
with its pads excluded from the cube, the cube welded to the palm (the pads' solref) and the
fingers locked where they touch it until the release step, when weld and lock let go and the
fingers open. Its count is what the friction grasp would cost if its hold were as cheap as the
weld's: the fingers' two slide joints and their constraints, without the pads' contacts.
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
from app.sim.model import CUBE_BODY, GRIP_WELD, GRIPPER_BODY, build_spec, finger_joint_name

C_LOOP = r"""
#include <stdio.h>
#include <mujoco/mujoco.h>
int main(int argc, char** argv) {
  mjModel* m = mj_loadModel(argv[1], NULL);
  FILE* f = fopen(argv[2], "r");
  int n_off, rows, off_ids[8];
  if (!m || !f || fscanf(f, "%d %d", &n_off, &rows) != 2 || n_off > 8) return 1;
  for (int j = 0; j < n_off; j++) if (fscanf(f, "%d", off_ids + j) != 1) return 1;
  mjData* d = mj_makeData(m);
  long nefc = 0;
  for (int r = 0; r < rows; r++) {
    int off;
    if (fscanf(f, "%d", &off) != 1) return 1;
    for (int i = 0; i < m->nu; i++) if (fscanf(f, "%lf", d->ctrl + i) != 1) return 1;
    if (off) for (int j = 0; j < n_off; j++) d->eq_active[off_ids[j]] = 0;
    for (int k = 0; k < 500; k++) { mj_step(m, d); nefc += d->nefc; }
  }
  printf("%ld\n", nefc);
  return 0;
}
"""


#: where the grasps' instructions differ (callgrind_annotate's per-function totals)
FUNCTIONS = (
    "mj_factorI",  # the mass matrix's factor (the chain, and the fingers at its end)
    "mj_solveLD",
    "mj_crb",
    "mju_cholFactorSymbolic",  # the constraint Hessian's factor (Newton)
    "mju_cholFactorNumeric",
    "mju_cholSolveSparse",
    "mju_sqrMatTDSparseNumeric",  # JᵀDJ: one term per constraint row
    "mju_transposeSparse",
    "mj_solPrimal",
    "mj_collision",
)


def hybrid_hold_model() -> mujoco.MjModel:
    """The ``--hybrid`` probe (module docstring): equalities "probe_weld" and "probe_lock"."""
    params = ArmParams(gripper=GripperParams(grasp="friction"))
    spec = build_spec("throw", "reference", params)
    weld = spec.add_equality(
        name="probe_weld", type=mujoco.mjtEq.mjEQ_WELD, objtype=mujoco.mjtObj.mjOBJ_BODY,
        name1=GRIPPER_BODY, name2=CUBE_BODY,
    )  # fmt: skip
    weld.data = [0.0] * 10 + [1.0] + [0.0] * (len(weld.data) - 11)  # pose at qpos0
    weld.solref = list(params.gripper.pad_solref)
    for side in ("left", "right"):
        spec.add_exclude(bodyname1=f"{side}_finger", bodyname2=CUBE_BODY)
    # the left finger held where its pad touches the cube (the coupling moves the right one)
    lock = spec.add_equality(
        name="probe_lock", type=mujoco.mjtEq.mjEQ_JOINT, name1=finger_joint_name("left")
    )
    lock.data = [params.gripper.pad_gap_m] + [0.0] * (len(lock.data) - 1)
    return spec.compile()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schedule", type=int, default=0, help="which P = 7 random θ (seed 7)")
    ap.add_argument("--hybrid", action="store_true", help="also count the hybrid-hold probe")
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
        per_fn: dict[str, dict[str, int]] = {fn: {} for fn in FUNCTIONS}
        for grasp in ("weld", "friction", *(("hybrid-probe",) if args.hybrid else ())):
            if grasp == "hybrid-probe":
                model = hybrid_hold_model()
            else:
                model = build_model(
                    "throw", "reference", ArmParams(gripper=GripperParams(grasp=grasp))
                )
            mujoco.mj_saveModel(model, str(work / f"{grasp}.mjb"), None)
            eq = (GRIP_WELD, "probe_weld", "probe_lock")
            off_ids = [
                i
                for n in eq
                if (i := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, n)) >= 0
            ]
            n_steps = d.pressure_schedule_pa.shape[0]
            lines = [f"{len(off_ids)} {n_steps} " + " ".join(map(str, off_ids))]
            for c, row in enumerate(d.pressure_schedule_pa):
                cmd = list(row) + ([1.0 if c < d.release_step else 0.0] if model.nu > 12 else [])
                off = int(c >= d.release_step)
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
            ann = subprocess.run(
                ["callgrind_annotate", f"{work / grasp}.cg"], capture_output=True, text=True
            ).stdout
            for fn in FUNCTIONS:
                hit = re.search(rf"^\s*([\d,]+) .*:{fn}[ .]", ann, re.MULTILINE)
                per_fn[fn][grasp] = int(hit.group(1).replace(",", "")) if hit else 0
    print(f"schedule {args.schedule} (t_R = {d.release_step}), preset reference, held commands")
    print("| grasp | instructions | constraint rows (sum over steps) | ratio to weld |")
    print("|---|---:|---:|---:|")
    for grasp, (n, rows) in counts.items():
        print(f"| {grasp} | {n:,} | {rows:,} | {n / counts['weld'][0]:.3f} |")
    print()
    print("| function (10⁶ instructions) | " + " | ".join(counts) + " |")
    print("|---|" + "---:|" * len(counts))
    for fn, by in per_fn.items():
        print(f"| `{fn}` | " + " | ".join(f"{by.get(g, 0) / 1e6:,.0f}" for g in counts) + " |")


if __name__ == "__main__":
    main()
