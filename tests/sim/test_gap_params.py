"""The two simulator parameters the stand-in's reality gap needs: a tip load and joint friction
(both 0 in the published simulator, so the default model is unchanged)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.sim import ArmParams
from app.sim.model import build_model, effective_params, hinge_joint_name


def test_tip_load_adds_its_mass_and_friction_reaches_every_hinge():
    base = ArmParams()
    m0 = build_model("tip_speed", "fast", base)
    assert np.all(m0.dof_frictionloss == 0.0)
    loaded = dataclasses.replace(
        base,
        tip_load_kg=0.12,
        joints=tuple(dataclasses.replace(j, frictionloss_nm=0.3) for j in base.joints),
    )
    m1 = build_model("tip_speed", "fast", loaded)
    assert m1.body_mass.sum() == pytest.approx(m0.body_mass.sum() + 0.12)
    assert m1.nbody == m0.nbody + 1 and m1.ngeom == m0.ngeom  # a mass, nothing to collide
    n = effective_params("fast", base).n_disks
    arm = {hinge_joint_name(j, a, i) for j in range(3) for a in "xy" for i in range(1, n)}
    rubbing = {
        m1.joint(i).name
        for i in range(m1.njnt)
        if m1.dof_frictionloss[m1.jnt_dofadr[i]] == pytest.approx(0.3)
    }
    assert rubbing == arm
    with pytest.raises(ValueError, match="tip_load_kg"):
        ArmParams(tip_load_kg=-1.0)
