"""The simulated soft arm (MuJoCo, built with MjSpec), its tasks, rollouts and presets.

>>> from app.sim import rollout
>>> res = rollout("tip_speed", schedule_pa)          # schedule_pa: (H, 12) Pa
>>> res.objective, res.max_tip_speed, res.trajectory.tip_pos_m.shape
>>> rollout("throw", schedule_pa, release_step=4, command_hold="linear", objective_rule="published")
"""

from app.policy import COMMAND_HOLDS, OBJECTIVE_RULES, check_command_hold, check_objective_rule
from app.sim.batch import RolloutPool, rollout_batch
from app.sim.model import TASKS, build_model, build_spec, export_xml
from app.sim.params import (
    ArmParams,
    ContinuumJointParams,
    CubeParams,
    ForcePlateParams,
    GripperParams,
    HammerParams,
    LinkParams,
)
from app.sim.presets import PRESETS, Preset
from app.sim.rollout import (
    Episode,
    RolloutResult,
    SimulationDiverged,
    Trajectory,
    check_rollout,
    rollout,
)

__all__ = [
    "COMMAND_HOLDS",
    "OBJECTIVE_RULES",
    "PRESETS",
    "TASKS",
    "ArmParams",
    "ContinuumJointParams",
    "CubeParams",
    "Episode",
    "ForcePlateParams",
    "GripperParams",
    "HammerParams",
    "LinkParams",
    "Preset",
    "RolloutPool",
    "RolloutResult",
    "SimulationDiverged",
    "Trajectory",
    "build_model",
    "build_spec",
    "check_command_hold",
    "check_objective_rule",
    "check_rollout",
    "export_xml",
    "rollout",
    "rollout_batch",
]
