"""Fidelity presets: physics options (and optionally disk count) for the same arm."""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco


@dataclass(frozen=True)
class Preset:
    """Physics options of one fidelity level.

    Attributes:
        name: preset name.
        timestep_s: physics step (s); 10 ms (the 100 Hz grid) must be a whole number of steps.
        integrator: "euler" or "implicitfast".
        solver: "newton" or "cg".
        iterations: constraint-solver iterations.
        tolerance: constraint-solver tolerance.
        ls_iterations: line-search iterations.
        cone: friction cone, "elliptic" or "pyramidal".
        jacobian: "dense", "sparse" or "auto".
        n_disks: disks per continuum joint, or None to take ``ArmParams.n_disks``.
        arm_self_collision: whether arm parts (disks, links) collide with one another; the
            disks of one continuum joint meet where its bend stops.
        grasp: the throw's grasp ("friction" or "weld"), or None to take
            ``GripperParams.grasp``. The friction grasp needs small steps: at 5 ms its stiff
            pad contacts fling or drop the cube (docs/bench/paper.md), so ``fast`` welds.
        weld_fingers_collide: whether the weld grasp's fingers strike the floor (as the
            friction grasp's and the published ones do) or pass through it (``fast-r1``).
    """

    name: str
    timestep_s: float
    integrator: str
    solver: str
    iterations: int
    tolerance: float
    ls_iterations: int
    cone: str
    jacobian: str
    n_disks: int | None = None
    arm_self_collision: bool = True
    grasp: str | None = None
    weld_fingers_collide: bool = True

    def apply(self, option: mujoco.MjOption | object) -> None:
        """Write these options onto a spec's or model's ``option``."""
        option.timestep = self.timestep_s
        option.integrator = _INTEGRATORS[self.integrator]
        option.solver = _SOLVERS[self.solver]
        option.iterations = self.iterations
        option.tolerance = self.tolerance
        option.ls_iterations = self.ls_iterations
        option.cone = _CONES[self.cone]
        option.jacobian = _JACOBIANS[self.jacobian]


_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
_JACOBIANS = {
    "dense": mujoco.mjtJacobian.mjJAC_DENSE,
    "sparse": mujoco.mjtJacobian.mjJAC_SPARSE,
    "auto": mujoco.mjtJacobian.mjJAC_AUTO,
}

# The published simulator's options: 1 ms, (semi-implicit) Euler, Newton, 50 iterations, 1e-10.
REFERENCE = Preset(
    name="reference",
    timestep_s=1e-3,
    integrator="euler",
    solver="newton",
    iterations=50,
    tolerance=1e-10,
    ls_iterations=50,
    cone="elliptic",
    jacobian="sparse",
)

# Same arm (10 disks: fewer disks change the geometry) and contacts, a 5x larger step with
# implicitfast and a loose solver; the cube is welded (the friction grasp needs the reference
# step). Revision 2 (session 12): the arm's self-contacts and the welded fingers' floor
# contacts, which put it within 10 % / 0.9 of every published reference case
# (docs/bench/paper.md (a‴)); revision 1 (``fast-r1``) had neither.
# Checked against REFERENCE by `handful bench sim` (docs/bench/sim.md).
FAST = Preset(
    name="fast",
    timestep_s=5e-3,
    integrator="implicitfast",
    solver="newton",
    iterations=8,
    tolerance=1e-6,
    ls_iterations=8,
    cone="pyramidal",
    jacobian="dense",
    grasp="weld",
)

# ``fast`` before session 12 (revision 1): no arm-on-arm contacts, so a joint could bend past
# where its disks meet, and the welded cube's fingers passed through the floor. Kept, and
# named, so that results made with it (the committed benchmark caches, experiments stored
# before migration 0010) reproduce; not for new work.
FAST_R1 = replace(FAST, name="fast-r1", arm_self_collision=False, weld_fingers_collide=False)

PRESETS: dict[str, Preset] = {p.name: p for p in (REFERENCE, FAST, FAST_R1)}


def get_preset(preset: str | Preset) -> Preset:
    """A preset by name (or itself); ValueError naming the choices if unknown."""
    if isinstance(preset, Preset):
        return preset
    try:
        return PRESETS[preset]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown preset {preset!r}; choose one of {', '.join(sorted(PRESETS))}"
        ) from None
