"""The soft arm, its tip loads and its task scenes, built in code with ``mujoco.MjSpec``.

Layout (ROBOT.md): a base box; three continuum joints, each ``n_disks`` thin cylinders joined by
x/y hinge pairs (springs/dampers in series: k·n, c·n per hinge; range = limit / n; anchors at
(0, 0, h) in the child disk's frame); two rigid links; an end-effector site 1.5 h above the last
disk with a velocimeter. Per joint, fixed tendons sum its x and its y hinges; each tendon carries
two cylinder actuators of opposite gear. Actuator order = chamber order: joint 0 (x+, x−, y+,
y−), joint 1, joint 2.

Tasks add their scene: ``throw`` a gripper and a 0.25 kg cube, ``hammer`` a 2 kg ball and a
force plate with a touch sensor, ``tip_speed`` nothing (the bare arm, as on the real robot).

The throw's grasp (``GripperParams.grasp``): ``"friction"`` builds two sliding fingers whose pads
(friction 0.7; the published inner 0.6 box optional) squeeze the free cube, driven by one more
actuator (``gripper``, after the 12 chambers; command 0 = open, any command ≥ ``GRIP_CLOSED_FROM``
= closed, finger force limited to ±``pad_force_n``), with touch sensors on the pads and the
published model's ``impratio`` 10 (its 5 no-slip iterations are optional, off by default);
``"weld"`` welds the cube to the palm (equality ``grip``) instead.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np

from app.policy import TASKS
from app.sim.params import ArmParams, LinkParams
from app.sim.presets import Preset, get_preset

EEF_SITE = "eef"
GRIP_WELD = "grip"
GRIP_ACTUATOR = "gripper"
GRIP_TENDON = "grip"
PAD_SENSORS = ("left_pad_touch", "right_pad_touch")
CUBE_ORIGIN_SENSOR = "cube_origin_pos"
CUBE_CENTRE_SITE = "cube_centre"
# The published gripper's command: 255 of a 275,800 full scale closes it fully.
GRIP_CLOSED_FROM = 255.0 / 275800.0
CUBE_BODY = "cube"
HAMMER_BODY = "hammer"
GRIPPER_BODY = "gripper"
PLATE_SENSOR = "plate_force"
EEF_VEL_SENSOR = "eef_vel"
EEF_POS_SENSOR = "eef_pos"
EEF_LINVEL_SENSOR = "eef_linvel"
OBJECT_POS_SENSOR = "object_pos"
OBJECT_LINVEL_SENSOR = "object_linvel"

_ORANGE = (0.8, 0.2, 0.1, 1.0)
_GREY = (0.5, 0.5, 0.5, 1.0)


def check_task(task: str) -> str:
    """Return ``task`` if known; ValueError naming the choices otherwise."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {', '.join(TASKS)}")
    return task


def hinge_joint_name(joint: int, axis: str, hinge: int) -> str:
    """Name of hinge ``hinge`` (1..n−1) about ``axis`` ("x"/"y") of continuum joint ``joint``."""
    return f"j{joint}_{axis}{hinge}"


def disk_body_name(joint: int, disk: int) -> str:
    """Name of disk ``disk`` (0..n−1) of continuum joint ``joint``."""
    return f"j{joint}_disk{disk}"


def tendon_name(joint: int, axis: str) -> str:
    """Fixed tendon summing joint ``joint``'s hinges about ``axis``: its bend (u for x, v for y)."""
    return f"j{joint}_{axis}"


def chamber_name(joint: int, axis: str, sign: str) -> str:
    """Actuator name of one chamber, as in app.policy.CHAMBER_NAMES (e.g. ``j0.x+``)."""
    return f"j{joint}.{axis}{sign}"


def _axis_angle_quat(axis: tuple[float, float, float], angle_rad: float) -> list[float]:
    a = np.asarray(axis, dtype=float)
    a /= np.linalg.norm(a)
    s = math.sin(angle_rad / 2.0)
    return [math.cos(angle_rad / 2.0), *(s * a)]


def _yaw_quat(angle_rad: float) -> list[float]:
    return _axis_angle_quat((0.0, 0.0, 1.0), angle_rad)


def _cylinder_inertia(mass: float, radius: float, height: float) -> list[float]:
    ixy = mass * (3.0 * radius**2 + height**2) / 12.0
    return [ixy, ixy, mass * radius**2 / 2.0]


def _set_inertial(
    body: mujoco.MjsBody, mass: float, pos: tuple[float, ...] | list[float], diag: list[float]
) -> None:
    body.explicitinertial = True
    body.mass = mass
    body.ipos = list(pos)
    body.inertia = list(diag)


class _Collision:
    """contype/conaffinity pairs: arm parts may be told not to collide with one another
    (``fast-r1``; every other preset keeps the arm's self-contacts, MuJoCo filtering parent and
    child, of which those between one joint's disks, where its bend stops, are nearly all:
    docs/bench/paper.md (a‴)), and the welded gripper's fingers to pass through the floor."""

    def __init__(self, arm_self_collision: bool, weld_fingers_collide: bool = True) -> None:
        self.weld_fingers_collide = weld_fingers_collide
        self.arm = (1, 1) if arm_self_collision else (2, 1)
        self.world = (1, 2)  # floor and plate: touch arm and objects
        self.obj = (3, 3)
        self.none = (0, 0)
        # the friction grasp's fingers touch the world (floor, base, plate) and the cube, never
        # the arm: the published gripper's fingers hit the floor when a swing brings the tip
        # down; its pads touch only the cube (bit 4), so their touch sensors mean the grip
        self.finger = (2, 0)
        self.pad = (4, 0)


def _geom(
    body: mujoco.MjsBody,
    name: str,
    gtype: mujoco.mjtGeom,
    size: list[float],
    rgba: tuple[float, ...],
    coll: tuple[int, int],
    **kw: object,
) -> mujoco.MjsGeom:
    g = body.add_geom(name=name, type=gtype, size=size, rgba=list(rgba), **kw)
    g.contype, g.conaffinity = coll
    return g


def _add_continuum_joint(
    spec: mujoco.MjSpec,
    parent: mujoco.MjsBody,
    j: int,
    params: ArmParams,
    pos: list[float],
    quat: list[float],
    coll: _Collision,
) -> mujoco.MjsBody:
    """Stack n disks under ``parent``; return the last disk."""
    jp = params.joints[j]
    n, h = params.n_disks, params.disk_height_m
    disk_mass = jp.mass_kg / n
    inertia = _cylinder_inertia(disk_mass, jp.disk_radius_m, h)
    hinge_limit = jp.bend_limit_rad / n
    body = parent.add_body(name=disk_body_name(j, 0), pos=pos, quat=quat)
    for i in range(n):
        if i > 0:
            body = body.add_body(name=disk_body_name(j, i), pos=[0.0, 0.0, 2.0 * h])
            for axis, vec in (("x", [1.0, 0.0, 0.0]), ("y", [0.0, 1.0, 0.0])):
                hinge = body.add_joint(
                    name=hinge_joint_name(j, axis, i),
                    type=mujoco.mjtJoint.mjJNT_HINGE,
                    axis=vec,
                    pos=[0.0, 0.0, h],
                    stiffness=[jp.stiffness_nm_rad * n, 0.0, 0.0],
                    damping=[jp.damping_nms_rad * n, 0.0, 0.0],
                    limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                    range=[-hinge_limit, hinge_limit],
                    group=3,
                )
                if jp.frictionloss_nm > 0.0:  # hinges in series: each carries the torque
                    hinge.frictionloss = jp.frictionloss_nm
        _set_inertial(body, disk_mass, (0.0, 0.0, 0.0), inertia)
        _geom(
            body,
            f"j{j}_disk{i}",
            mujoco.mjtGeom.mjGEOM_CYLINDER,
            [jp.disk_radius_m, h / 2.0, 0.0],
            _ORANGE,
            coll.arm,
        )
    return body


def _add_link(
    last_disk: mujoco.MjsBody, k: int, lp: LinkParams, h: float, coll: _Collision
) -> mujoco.MjsBody:
    link = last_disk.add_body(name=f"link{k}", pos=[0.0, 0.0, h / 2.0])
    _set_inertial(link, lp.mass_kg, lp.com_m, list(lp.inertia_kgm2))
    # A capsule stands in for the CAD mesh; kept clear of the disks it is not welded to.
    end = np.asarray(lp.next_joint_pos_m)
    r = lp.capsule_radius_m
    end_short = end * (1.0 - (r + 2.0 * h) / np.linalg.norm(end))
    _geom(
        link,
        f"link{k}",
        mujoco.mjtGeom.mjGEOM_CAPSULE,
        [r, 0.0, 0.0],
        _GREY,
        coll.arm,
        fromto=[0.0, 0.0, r, *end_short.tolist()],
    )
    return link


def _build_arm(spec: mujoco.MjSpec, params: ArmParams, coll: _Collision) -> mujoco.MjsBody:
    """Base, joints, links, tendons, actuators, sensors. Returns the last disk of joint 2."""
    h = params.disk_height_m
    hx, hy, hz = params.base_half_size_m
    base = spec.worldbody.add_body(
        name="base", pos=[0.0, 0.0, hz], quat=_yaw_quat(params.base_yaw_rad)
    )
    _geom(base, "base", mujoco.mjtGeom.mjGEOM_BOX, [hx, hy, hz], (0.1, 0.1, 0.1, 1.0), coll.world)
    _set_inertial(base, 0.0136, (0.0, 0.0, 0.0), [8.497e-4, 8.497e-4, 1.6992e-3])

    last = _add_continuum_joint(
        spec, base, 0, params, [0.0, 0.0, hz + h / 2.0], _yaw_quat(-params.base_yaw_rad), coll
    )
    for k, lp in enumerate(params.links):
        link = _add_link(last, k, lp, h, coll)
        last = _add_continuum_joint(
            spec,
            link,
            k + 1,
            params,
            list(lp.next_joint_pos_m),
            _axis_angle_quat(lp.next_joint_axis, lp.next_joint_angle_rad),
            coll,
        )
    last.add_site(
        name=EEF_SITE,
        pos=[0.0, 0.0, params.eef_offset_disk_heights * h],
        size=[0.01, 0.0, 0.0],
        rgba=[0.0, 0.0, 1.0, 1.0],
    )

    for j, jp in enumerate(params.joints):
        for axis in ("x", "y"):
            tendon = spec.add_tendon(name=tendon_name(j, axis))
            for i in range(1, params.n_disks):
                tendon.wrap_joint(hinge_joint_name(j, axis, i), 1.0)
        for axis in ("x", "y"):
            for sign, gear in (("+", jp.moment_arm_m), ("-", -jp.moment_arm_m)):
                act = spec.add_actuator(
                    name=chamber_name(j, axis, sign),
                    trntype=mujoco.mjtTrn.mjTRN_TENDON,
                    target=tendon_name(j, axis),
                )
                act.set_to_cylinder(jp.time_constant_s, 0.0, jp.chamber_area_m2)
                act.gear = [gear, 0.0, 0.0, 0.0, 0.0, 0.0]
                act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
                act.ctrlrange = [0.0, params.max_pressure_pa]

    spec.add_sensor(
        name=EEF_VEL_SENSOR,
        type=mujoco.mjtSensor.mjSENS_VELOCIMETER,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname=EEF_SITE,
    )
    sens = mujoco.mjtSensor
    for sname, stype in (
        (EEF_POS_SENSOR, sens.mjSENS_FRAMEPOS),
        (EEF_LINVEL_SENSOR, sens.mjSENS_FRAMELINVEL),
    ):
        spec.add_sensor(name=sname, type=stype, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=EEF_SITE)
    bend_sensors = ((sens.mjSENS_TENDONPOS, ""), (sens.mjSENS_TENDONVEL, "d"))
    for stype, suffix in bend_sensors:
        for j in range(len(params.joints)):
            for axis, bend in (("x", "u"), ("y", "v")):
                spec.add_sensor(
                    name=f"{bend}{suffix}{j}",
                    type=stype,
                    objtype=mujoco.mjtObj.mjOBJ_TENDON,
                    objname=tendon_name(j, axis),
                )
    return last


def _add_object_sensors(
    spec: mujoco.MjSpec, name: str, objtype: mujoco.mjtObj = mujoco.mjtObj.mjOBJ_XBODY
) -> None:
    """World-frame position and linear velocity of a task object's centre (a body or site)."""
    sens = mujoco.mjtSensor
    for sname, stype in (
        (OBJECT_POS_SENSOR, sens.mjSENS_FRAMEPOS),
        (OBJECT_LINVEL_SENSOR, sens.mjSENS_FRAMELINVEL),
    ):
        spec.add_sensor(name=sname, type=stype, objtype=objtype, objname=name)


def _add_world(spec: mujoco.MjSpec, coll: _Collision) -> None:
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.2, 0.3, 0.4],
        rgb2=[0.1, 0.15, 0.2],
        width=512,
        height=512,
    )
    mat = spec.add_material(name="floor", texuniform=True, texrepeat=[4.0, 4.0], reflectance=0.2)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    _geom(
        spec.worldbody,
        "floor",
        mujoco.mjtGeom.mjGEOM_PLANE,
        [0.0, 0.0, 0.05],
        (1.0, 1.0, 1.0, 1.0),
        coll.world,
        material="floor",
    )
    spec.worldbody.add_light(
        name="sun",
        pos=[0.0, 0.0, 4.0],
        dir=[0.0, 0.0, -1.0],
        diffuse=[0.6, 0.6, 0.6],
        specular=[0.2, 0.2, 0.2],
    )


def _add_gripper(tip: mujoco.MjsBody, params: ArmParams, coll: _Collision) -> mujoco.MjsBody:
    """The two-finger gripper at the end-effector site (frame = the site's frame).

    Weld grasp: palm and fingers lumped in one rigid body. Friction grasp: the palm, and two
    fingers on slide joints (closing towards the tip axis, kept symmetric by an equality) with
    two pad boxes each facing the cube.
    """
    gp = params.gripper
    site_z = params.eef_offset_disk_heights * params.disk_height_m
    body = tip.add_body(name=GRIPPER_BODY, pos=[0.0, 0.0, site_z])
    if gp.grasp == "weld":
        m = gp.mass_kg
        com = (gp.palm_mass_kg * gp.palm_com_m + gp.finger_mass_kg * gp.finger_com_m) / m
        palm = _cylinder_inertia(gp.palm_mass_kg, gp.palm_radius_m, gp.palm_length_m)
        half_sep = gp.finger_separation_m / 2.0
        # Parallel-axis sums about the combined centre of mass (fingers as two point masses).
        dp, df = gp.palm_com_m - com, gp.finger_com_m - com
        ixx = palm[0] + gp.palm_mass_kg * dp**2 + gp.finger_mass_kg * (df**2 + half_sep**2)
        iyy = palm[1] + gp.palm_mass_kg * dp**2 + gp.finger_mass_kg * df**2
        izz = palm[2] + gp.finger_mass_kg * half_sep**2
        _set_inertial(body, m, (0.0, 0.0, com), [ixx, iyy, izz])
    else:
        inertia = _cylinder_inertia(gp.palm_mass_kg, gp.palm_radius_m, gp.palm_length_m)
        _set_inertial(body, gp.palm_mass_kg, (0.0, 0.0, gp.palm_com_m), inertia)
    _geom(
        body,
        "palm",
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        [gp.palm_radius_m, gp.palm_length_m / 2.0, 0.0],
        (0.15, 0.15, 0.15, 1.0),
        coll.arm,
        pos=[0.0, 0.0, gp.palm_length_m / 2.0],
    )
    if gp.grasp == "weld":
        # the friction grasp's finger boxes where they close on the cube: they strike the
        # floor as the published fingers do (docs/bench/paper.md (a‴))
        x = params.cube.side_m / 2.0 + PAD_HALF[0] + FINGER_BOX_X_M
        tip_len = gp.finger_tip_m - gp.palm_length_m
        finger = coll.finger if coll.weld_fingers_collide else coll.none
        for side, sign in (("left", -1.0), ("right", 1.0)):
            box = _finger_geom(body, side, sign * x, gp.palm_length_m, tip_len, finger)
            box.solref = list(gp.finger_solref)
        return body
    _add_fingers(body, params, coll)
    return body


def _finger_geom(
    body: mujoco.MjsBody,
    side: str,
    x: float,
    palm_length_m: float,
    finger_len: float,
    coll: tuple[int, int],
) -> mujoco.MjsGeom:
    """A finger's box (the same for either grasp) at ``x``, from the palm's end outwards."""
    return _geom(
        body,
        f"{side}_finger",
        mujoco.mjtGeom.mjGEOM_BOX,
        [0.008, 0.012, finger_len / 2.0],
        (0.3, 0.3, 0.3, 1.0),
        coll,
        pos=[x, 0.0, palm_length_m + finger_len / 2.0],
    )


PAD_HALF = (0.004, 0.011, 0.009375)  # a pad box's half sizes: thickness, width, length (m)
FINGER_BOX_X_M = 0.012  # a finger's collision box centre, outwards from its pads' centre (m)


def _add_fingers(palm: mujoco.MjsBody, params: ArmParams, coll: _Collision) -> None:
    gp, cp = params.gripper, params.cube
    finger_mass = gp.finger_mass_kg / 2.0
    # the pads' faces start pad_gap_m from the cube's faces; pad 1 (outer) is centred
    # ``pad_z_m`` beyond the site, pad 2 lies next to it towards the palm
    origin_z = gp.pad_z_m
    pad_x = cp.side_m / 2.0 + gp.pad_gap_m + PAD_HALF[0]
    # armature so that force / (mass + armature) covers the gap in close_time_s
    eff_mass = gp.pad_force_n * gp.close_time_s**2 / (2.0 * gp.pad_gap_m)
    armature = max(eff_mass - finger_mass, 0.0)
    for side, sign in (("left", -1.0), ("right", 1.0)):
        finger = palm.add_body(name=f"{side}_finger", pos=[sign * pad_x, 0.0, 0.0])
        finger.add_joint(
            name=finger_joint_name(side),
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=[-sign, 0.0, 0.0],  # + closes
            range=[0.0, gp.pad_gap_m + cp.side_m / 2.0],
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            armature=armature,
            damping=0.1,
        )
        _set_inertial(finger, finger_mass, (0.0, 0.0, gp.finger_com_m), [1e-5, 1e-5, 1e-6])
        # the finger's collision box: outside its pads, from the palm to the fingertip; on a
        # massless child body, so the pads' touch sensors (which count their own body's
        # contacts) never read its floor contacts as the grip
        frame = finger.add_body(name=f"{side}_finger_frame")
        _set_inertial(frame, 0.0, (0.0, 0.0, 0.0), [0.0, 0.0, 0.0])
        tip_len = gp.finger_tip_m - gp.palm_length_m
        box = _finger_geom(
            frame, side, sign * FINGER_BOX_X_M, gp.palm_length_m, tip_len, coll.finger
        )
        box.solref = list(gp.finger_solref)
        # pad k lies k pad lengths nearer the palm than pad 1
        for k, mu in enumerate(gp.pad_friction):
            z = origin_z - 2.0 * k * PAD_HALF[2]
            pad = _geom(
                finger,
                f"{side}_pad{k + 1}",
                mujoco.mjtGeom.mjGEOM_BOX,
                list(PAD_HALF),
                (0.55, 0.55, 0.55, 1.0),
                coll.pad,
                pos=[0.0, 0.0, z],
            )
            pad.friction = [mu, 0.005, 0.0001]
            pad.priority = 1
            pad.solref = list(gp.pad_solref)
            pad.solimp = [*gp.pad_solimp, 0.5, 2.0]
        finger.add_site(
            name=f"{side}_pad_site",
            pos=[0.0, 0.0, origin_z - PAD_HALF[2]],
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[PAD_HALF[0] + 0.002, PAD_HALF[1] + 0.002, 2.0 * PAD_HALF[2] + 0.002],
            rgba=[0.0, 1.0, 0.0, 0.0],
        )


def finger_joint_name(side: str) -> str:
    """The slide joint of the ``"left"`` or ``"right"`` finger (friction grasp)."""
    return f"{side}_finger_slide"


def _add_grip_drive(spec: mujoco.MjSpec, params: ArmParams) -> None:
    """The friction grasp's drive: one actuator on both fingers, their coupling, pad sensors."""
    gp = params.gripper
    tendon = spec.add_tendon(name=GRIP_TENDON)
    for side in ("left", "right"):
        tendon.wrap_joint(finger_joint_name(side), 1.0)
    spec.add_equality(
        name="finger_sync",
        type=mujoco.mjtEq.mjEQ_JOINT,
        name1=finger_joint_name("left"),
        name2=finger_joint_name("right"),
    )
    # force = F·(2·ctrl / GRIP_CLOSED_FROM − 1), clipped to ±F: −F (opening) at 0, +F
    # (closing) from GRIP_CLOSED_FROM on; each finger gets the tendon's force.
    act = spec.add_actuator(
        name=GRIP_ACTUATOR, trntype=mujoco.mjtTrn.mjTRN_TENDON, target=GRIP_TENDON
    )
    f = gp.pad_force_n
    act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
    act.gainprm = [2.0 * f / GRIP_CLOSED_FROM] + [0.0] * (len(act.gainprm) - 1)
    act.biasprm = [-f] + [0.0] * (len(act.biasprm) - 1)
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.ctrlrange = [0.0, 1.0]
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.forcerange = [-f, f]
    for sensor, side in zip(PAD_SENSORS, ("left", "right"), strict=True):
        spec.add_sensor(
            name=sensor,
            type=mujoco.mjtSensor.mjSENS_TOUCH,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            objname=f"{side}_pad_site",
        )
    spec.option.impratio = gp.impratio
    spec.option.noslip_iterations = int(gp.noslip_iterations)


def _add_cube(
    spec: mujoco.MjSpec, params: ArmParams, pos: np.ndarray, quat: np.ndarray, coll: _Collision
) -> None:
    """The cube, its body origin ``origin_offset_m`` from the box centre towards the palm."""
    cp = params.cube
    body = spec.worldbody.add_body(name=CUBE_BODY, pos=pos.tolist(), quat=quat.tolist())
    body.add_freejoint(name="cube_free")
    half = cp.side_m / 2.0
    i = cp.mass_kg * cp.side_m**2 / 6.0
    centre = [0.0, 0.0, cp.origin_offset_m]
    _set_inertial(body, cp.mass_kg, centre, [i, i, i])
    cube = _geom(
        body,
        CUBE_BODY,
        mujoco.mjtGeom.mjGEOM_BOX,
        [half] * 3,
        (0.2, 0.7, 0.0, 1.0),
        (coll.obj[0], coll.obj[1] | 4),  # the pads touch it
        pos=centre,
    )
    if params.gripper.grasp == "friction":
        cube.solref = list(params.gripper.cube_solref)
    body.add_site(name=CUBE_CENTRE_SITE, pos=centre, size=[0.005, 0.0, 0.0])
    spec.add_exclude(bodyname1=GRIPPER_BODY, bodyname2=CUBE_BODY)
    if params.gripper.grasp == "weld":
        weld = spec.add_equality(
            name=GRIP_WELD,
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1=GRIPPER_BODY,
            name2=CUBE_BODY,
        )
        # anchor, relpos, relquat = 0 (take the relative pose from qpos0), torquescale = 1
        weld.data = [0.0] * 10 + [1.0] + [0.0] * (len(weld.data) - 11)
    spec.add_sensor(
        name=CUBE_ORIGIN_SENSOR,
        type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
        objtype=mujoco.mjtObj.mjOBJ_XBODY,
        objname=CUBE_BODY,
    )


def _add_hammer(tip: mujoco.MjsBody, params: ArmParams, coll: _Collision) -> None:
    hp = params.hammer
    site_z = params.eef_offset_disk_heights * params.disk_height_m
    body = tip.add_body(name=HAMMER_BODY, pos=[0.0, 0.0, site_z + hp.radius_m])
    i = 0.4 * hp.mass_kg * hp.radius_m**2
    _set_inertial(body, hp.mass_kg, (0.0, 0.0, 0.0), [i, i, i])
    _geom(
        body,
        HAMMER_BODY,
        mujoco.mjtGeom.mjGEOM_SPHERE,
        [hp.radius_m, 0.0, 0.0],
        (0.2, 0.7, 0.0, 1.0),
        coll.obj,
    )


def _add_plate(spec: mujoco.MjSpec, params: ArmParams, coll: _Collision) -> None:
    pp = params.plate
    r, half_t = pp.diameter_m / 2.0, pp.thickness_m / 2.0
    cx, cy, cz = pp.centre_m
    centre = [cx, cy, cz + half_t]  # the plate lies on the floor: bottom face at z = cz
    _geom(
        spec.worldbody,
        "plate",
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        [r, half_t, 0.0],
        (1.0, 0.0, 0.0, 1.0),
        coll.world,
        pos=centre,
    )
    spec.worldbody.add_site(
        name="plate_touch",
        pos=centre,
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[1.01 * r, 1.01 * half_t, 0.0],
        rgba=[1.0, 0.0, 0.0, 0.1],
    )
    spec.add_sensor(
        name=PLATE_SENSOR,
        type=mujoco.mjtSensor.mjSENS_TOUCH,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname="plate_touch",
    )


TIP_LOAD_RADIUS_M = 0.03  # the tip load's inertia is a solid sphere's of this radius


def _add_tip_load(tip: mujoco.MjsBody, params: ArmParams) -> None:
    """``params.tip_load_kg`` at the end-effector site: a body with mass and no geom."""
    h = params.disk_height_m
    load = tip.add_body(name="tip_load", pos=[0.0, 0.0, params.eef_offset_disk_heights * h])
    i = 0.4 * params.tip_load_kg * TIP_LOAD_RADIUS_M**2
    _set_inertial(load, params.tip_load_kg, (0.0, 0.0, 0.0), [i, i, i])


def effective_params(preset: str | Preset, params: ArmParams | None) -> ArmParams:
    """The ArmParams a preset actually builds (a preset may fix the disk count and the grasp)."""
    p = get_preset(preset)
    params = params if params is not None else ArmParams()
    if not isinstance(params, ArmParams):
        raise ValueError(f"params must be an ArmParams, got {type(params).__name__}")
    if p.n_disks is not None and p.n_disks != params.n_disks:
        params = replace(params, n_disks=p.n_disks)
    if p.grasp is not None and p.grasp != params.gripper.grasp:
        params = replace(params, gripper=replace(params.gripper, grasp=p.grasp))
    return params


def build_spec(
    task: str, preset: str | Preset = "reference", params: ArmParams | None = None
) -> mujoco.MjSpec:
    """An MjSpec of the arm in ``task``'s scene with ``preset``'s physics options."""
    check_task(task)
    p = get_preset(preset)
    params = effective_params(p, params)
    coll = _Collision(p.arm_self_collision, p.weld_fingers_collide)

    spec = mujoco.MjSpec()
    spec.modelname = f"handful_{task}_{p.name}"
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    p.apply(spec.option)
    spec.option.gravity = list(params.gravity_m_s2)
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 720

    _add_world(spec, coll)
    tip = _build_arm(spec, params, coll)
    if params.tip_load_kg > 0.0:
        _add_tip_load(tip, params)
    if task == "hammer":
        _add_hammer(tip, params, coll)
        _add_plate(spec, params, coll)
        _add_object_sensors(spec, HAMMER_BODY)
    elif task == "throw":
        _add_gripper(tip, params, coll)
        # The cube starts between the pads: place it where the gripper holds it at qpos0.
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        sid = model.site(EEF_SITE).id
        rot = data.site_xmat[sid].reshape(3, 3)
        origin = params.cube.hold_offset_m - params.cube.origin_offset_m
        pos = data.site_xpos[sid] + rot @ np.array([0.0, 0.0, origin])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rot.ravel())
        _add_cube(spec, params, pos, quat, coll)
        _add_object_sensors(spec, CUBE_CENTRE_SITE, mujoco.mjtObj.mjOBJ_SITE)
        if params.gripper.grasp == "friction":
            _add_grip_drive(spec, params)
    return spec


def build_model(
    task: str, preset: str | Preset = "reference", params: ArmParams | None = None
) -> mujoco.MjModel:
    """The compiled model of the arm in ``task``'s scene (see module docstring)."""
    return build_spec(task, preset, params).compile()


def export_xml(
    task: str,
    path: str | Path | None = None,
    *,
    preset: str | Preset = "reference",
    params: ArmParams | None = None,
) -> str:
    """MJCF of the compiled model (open it in MuJoCo's viewer); also written to ``path``."""
    spec = build_spec(task, preset, params)
    spec.compile()
    xml = spec.to_xml()
    if path is not None:
        Path(path).write_text(xml)
    return xml
