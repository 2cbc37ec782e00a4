"""The compiled arm carries the facts of ROBOT.md (cheap: compile only, no episodes)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from app.policy import CHAMBER_NAMES, SIM_MAX_PRESSURE_PA
from app.sim import TASKS, ArmParams, GripperParams, build_model, export_xml
from app.sim.model import EEF_SITE, disk_body_name, hinge_joint_name

PARAMS = ArmParams()
H = 0.2 / 19  # disk height at 10 disks


@pytest.fixture(scope="module")
def arm() -> mujoco.MjModel:
    return build_model("tip_speed")


def test_disk_layout_and_inertia(arm: mujoco.MjModel) -> None:
    assert PARAMS.disk_height_m == pytest.approx(H)
    for j, (radius, mass) in enumerate(((0.125, 2.653), (0.08, 1.326), (0.08, 1.326))):
        m = mass / 10
        for i in range(10):
            b = arm.body(disk_body_name(j, i))
            assert b.mass[0] == pytest.approx(m)
            ixy = m * (3 * radius**2 + H**2) / 12
            np.testing.assert_allclose(b.inertia, [ixy, ixy, m * radius**2 / 2], rtol=1e-9)
            if i > 0:
                np.testing.assert_allclose(b.pos, [0, 0, 2 * H], atol=1e-12)
    assert arm.nv == 54  # 3 joints × 9 universal joints × 2 hinges


def test_hinges_springs_in_series_and_anchor(arm: mujoco.MjModel) -> None:
    for j, (k, c, limit_deg) in enumerate(((136, 7.5, 50), (27, 2, 90), (27, 2, 90))):
        for axis, vec in (("x", [1, 0, 0]), ("y", [0, 1, 0])):
            for i in range(1, 10):
                jnt = arm.joint(hinge_joint_name(j, axis, i))
                assert jnt.stiffness[0] == pytest.approx(k * 10)
                assert arm.dof_damping[jnt.dofadr[0]] == pytest.approx(c * 10)
                np.testing.assert_allclose(jnt.range, np.radians([-limit_deg, limit_deg]) / 10)
                np.testing.assert_allclose(jnt.pos, [0, 0, H], atol=1e-12)
                np.testing.assert_allclose(jnt.axis, vec)


def test_base_and_first_disk_pose(arm: mujoco.MjModel) -> None:
    data = mujoco.MjData(arm)
    mujoco.mj_kinematics(arm, data)
    first = arm.body(disk_body_name(0, 0)).id
    np.testing.assert_allclose(data.xpos[first], [0, 0, 0.28 + H / 2], atol=1e-12)
    # the base's +45° and the first disk's −45° cancel: the first disk is unrotated
    np.testing.assert_allclose(data.xmat[first].reshape(3, 3), np.eye(3), atol=1e-12)
    geom = arm.geom("base")
    np.testing.assert_allclose(geom.size, [0.19685, 0.19685, 0.14])
    link0, link1 = arm.body("link0"), arm.body("link1")
    assert link0.mass[0] == pytest.approx(3.881) and link1.mass[0] == pytest.approx(3.474)
    np.testing.assert_allclose(link0.ipos, [0, 0, 0.115])
    np.testing.assert_allclose(link1.ipos, [-0.07, 0.07, 0.13])
    np.testing.assert_allclose(link0.inertia, [0.108, 0.108, 0.023])
    np.testing.assert_allclose(link1.inertia, [0.05, 0.05, 0.017])
    np.testing.assert_allclose(arm.body(disk_body_name(1, 0)).pos, [-0.0223, 0.0223, 0.282])
    np.testing.assert_allclose(arm.body(disk_body_name(2, 0)).pos, [-0.103, 0.103, 0.190])
    a = math.radians(-45) / 2
    expected_quat = [math.cos(a), math.sin(a) / math.sqrt(2), math.sin(a) / math.sqrt(2), 0]
    np.testing.assert_allclose(arm.body(disk_body_name(2, 0)).quat, expected_quat, atol=1e-12)


def test_end_effector_site_above_last_disk(arm: mujoco.MjModel) -> None:
    site = arm.site(EEF_SITE)
    assert site.bodyid[0] == arm.body(disk_body_name(2, 9)).id
    np.testing.assert_allclose(site.pos, [0, 0, 1.5 * H], atol=1e-12)


def test_actuators_follow_chamber_order(arm: mujoco.MjModel) -> None:
    names = tuple(arm.actuator(i).name for i in range(arm.nu))
    assert names == CHAMBER_NAMES
    areas = (math.pi * (0.05 * math.sqrt(2)) ** 2 / 4, math.pi * 0.05**2 / 4, math.pi * 0.05**2 / 4)
    for u in range(12):
        j, pair, sign = u // 4, (u % 4) // 2, 1 - 2 * (u % 2)
        act = arm.actuator(u)
        assert arm.tendon(act.trnid[0]).name == f"j{j}_{'xy'[pair]}"
        assert act.gear[0] == pytest.approx(sign * (0.10, 0.05, 0.05)[j])
        assert act.gainprm[0] == pytest.approx(areas[j])
        assert act.dynprm[0] == pytest.approx((0.2, 0.5, 0.8)[j])
        np.testing.assert_allclose(act.ctrlrange, [0, SIM_MAX_PRESSURE_PA])
    # each tendon sums its joint's nine x (or y) hinges with coefficient 1
    assert arm.ntendon == 6
    np.testing.assert_array_equal(arm.tendon_num, [9] * 6)
    np.testing.assert_array_equal(arm.wrap_prm[: arm.nwrap], np.ones(arm.nwrap))


def test_task_loads() -> None:
    bare = build_model("tip_speed")
    hammer = build_model("hammer")
    throw = build_model("throw")
    arm_mass = bare.body_subtreemass[0]
    assert hammer.body_subtreemass[0] - arm_mass == pytest.approx(2.0)
    assert hammer.body("hammer").pos[2] == pytest.approx(1.5 * H + 0.08)
    assert throw.body_subtreemass[throw.body("gripper").id] == pytest.approx(0.90)
    assert throw.body("cube").mass[0] == pytest.approx(0.25)
    plate = hammer.geom("plate")
    np.testing.assert_allclose(plate.size[:2], [0.25, 0.01])
    np.testing.assert_allclose(plate.pos, [-0.5, 0.5, 0.01])
    assert hammer.body("hammer").mass[0] == pytest.approx(2.0)
    # the cube's centre starts 0.162 m beyond the tip along the tip's axis, its body origin
    # 1.25 cm nearer; between the open pads (friction grasp): no weld, no contact yet
    data = mujoco.MjData(throw)
    mujoco.mj_forward(throw, data)
    tip = data.site_xpos[throw.site(EEF_SITE).id]
    axis = data.site_xmat[throw.site(EEF_SITE).id].reshape(3, 3)[:, 2]
    centre = data.site_xpos[throw.site("cube_centre").id]
    np.testing.assert_allclose(centre, tip + 0.162 * axis, atol=1e-9)
    np.testing.assert_allclose(data.xpos[throw.body("cube").id], tip + 0.1495 * axis, atol=1e-9)
    assert throw.neq == 1 and throw.nu == 13 and data.ncon == 0  # the fingers' coupling only
    assert throw.opt.impratio == 10.0
    # the weld option (and the fast preset) weld it instead, active from the start
    welded = build_model("throw", params=ArmParams(gripper=GripperParams(grasp="weld")))
    assert welded.body("gripper").mass[0] == pytest.approx(0.90) and welded.nu == 12
    assert welded.equality("grip").id >= 0 and welded.eq_active0[0] == 1
    assert build_model("throw", "fast").nu == 12
    with pytest.raises(ValueError, match="unknown grasp 'glue'"):
        GripperParams(grasp="glue")
    with pytest.raises(ValueError, match=r"cube_solref needs a time constant > 0 s .*\(0.0, 1.0\)"):
        GripperParams(cube_solref=(0.0, 1.0))
    # the friction grasp's fingers and cube meet the world softly (they stand in for the
    # published linkage's give); the weld (and so the fast preset) keeps MuJoCo's default
    np.testing.assert_allclose(throw.geom_solref[throw.geom("cube").id], [0.08, 0.3])
    np.testing.assert_allclose(throw.geom_solref[throw.geom("left_finger").id], [0.08, 1.0])
    np.testing.assert_allclose(welded.geom_solref[welded.geom("cube").id], [0.02, 1.0])


def test_friction_fingers_hit_the_floor_and_the_pads_touch_only_the_cube() -> None:
    throw = build_model("throw")

    def collides(a: int, b: int) -> bool:
        ga, gb = throw.geom_contype, throw.geom_conaffinity
        return bool(ga[a] & gb[b] or ga[b] & gb[a])

    floor, cube = throw.geom("floor").id, throw.geom("cube").id
    arm = [g for g in range(throw.ngeom) if throw.geom(g).name.startswith(("j", "link"))]
    data = mujoco.MjData(throw)
    mujoco.mj_forward(throw, data)
    tip = data.site_xpos[throw.site(EEF_SITE).id]
    axis = data.site_xmat[throw.site(EEF_SITE).id].reshape(3, 3)[:, 2]
    for side in ("left", "right"):
        finger, pad = throw.geom(f"{side}_finger").id, throw.geom(f"{side}_pad1").id
        assert collides(finger, floor) and collides(finger, cube)
        assert not any(collides(finger, g) for g in arm)
        assert collides(pad, cube) and not collides(pad, floor)  # its touch sensor = the grip
        # the fingers reach 0.17 m beyond the site, the outer pad centred 0.1615 m beyond it
        far = (data.geom_xpos[finger] - tip) @ axis + throw.geom_size[finger][2]
        assert far == pytest.approx(0.17, abs=1e-9)
        assert (data.geom_xpos[pad] - tip) @ axis == pytest.approx(0.1615, abs=1e-9)


@pytest.mark.parametrize(
    ("preset", "same_joint", "other_joints", "weld_fingers_on_floor"),
    [
        ("reference", True, True, None),
        ("fast", True, True, True),
        ("fast-r1", False, False, False),
    ],
)
def test_which_arm_parts_touch_one_another_in_each_preset(
    preset: str, same_joint: bool, other_joints: bool, weld_fingers_on_floor: bool | None
) -> None:
    """``fast`` keeps the arm's self-contacts (one joint's disks meet where its bend stops);
    its welded fingers strike the floor 0.17 m beyond the site, as the friction grasp's do.
    ``fast-r1`` had neither."""
    m = build_model("throw", preset)

    def collides(a: str, b: str) -> bool:
        ga, gb = m.geom(a).id, m.geom(b).id
        t, c = m.geom_contype, m.geom_conaffinity
        return bool(t[ga] & c[gb] or t[gb] & c[ga])

    assert collides("j0_disk1", "j0_disk3") is same_joint
    assert collides("j2_disk2", "j2_disk5") is same_joint
    assert collides("j0_disk5", "j2_disk8") is other_joints
    assert collides("link0", "j2_disk4") is other_joints
    assert collides("j1_disk3", "floor") and collides("link1", "floor")  # the world: always
    if weld_fingers_on_floor is not None:
        for side in ("left", "right"):
            assert collides(f"{side}_finger", "floor") is weld_fingers_on_floor
            assert not collides(f"{side}_finger", "j2_disk9")
        data = mujoco.MjData(m)
        mujoco.mj_forward(m, data)
        tip = data.site_xpos[m.site(EEF_SITE).id]
        axis = data.site_xmat[m.site(EEF_SITE).id].reshape(3, 3)[:, 2]
        finger = m.geom("left_finger").id
        if weld_fingers_on_floor:
            far = (data.geom_xpos[finger] - tip) @ axis + m.geom_size[finger][2]
            assert far == pytest.approx(0.17, abs=1e-9)


def test_gravity_and_reference_options() -> None:
    m = build_model("hammer", "reference")
    assert m.opt.timestep == 1e-3 and m.opt.iterations == 50 and m.opt.tolerance == 1e-10
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert m.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -9.81])


@pytest.mark.parametrize("task", TASKS)
def test_exported_xml_reloads_to_the_same_dynamics(task: str, tmp_path) -> None:
    path = tmp_path / f"{task}.xml"
    export_xml(task, path, preset="fast")
    reloaded = mujoco.MjModel.from_xml_path(str(path))
    original = build_model(task, "fast")
    assert (reloaded.nq, reloaded.nv, reloaded.nu) == (original.nq, original.nv, original.nu)
    states = []
    for m in (original, reloaded):
        d = mujoco.MjData(m)
        d.ctrl[:] = np.linspace(0, 2e5, 12)
        mujoco.mj_step(m, d, 50)
        states.append(d.qpos.copy())
    # MJCF stores numbers to 6 significant digits: same dynamics up to that rounding
    np.testing.assert_allclose(states[0], states[1], atol=1e-5)
