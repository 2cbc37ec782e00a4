"""A small MuJoCo arm built inline for the 3D-view tests: every geom kind the viewer draws."""

from __future__ import annotations

import mujoco
import numpy as np

G = mujoco.mjtGeom


def small_arm(task: str = "throw", preset: str = "reference") -> mujoco.MjModel:
    """Floor, a plate, a base box, two hinged capsule/cylinder links and a free cube."""
    del task, preset
    spec = mujoco.MjSpec()
    world = spec.worldbody
    world.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], rgba=[0.8, 0.8, 0.8, 1])
    world.add_geom(
        name="plate",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[0.25, 0.01, 0],
        pos=[-0.5, 0.5, 0.01],
        rgba=[0.9, 0.3, 0.2, 1],
    )
    base = world.add_body(name="base", pos=[0, 0, 0.14])
    base.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.19, 0.19, 0.14], rgba=[0.3, 0.3, 0.3, 1])
    link0 = base.add_body(name="link0", pos=[0, 0, 0.14])
    link0.add_joint(name="j0", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0])
    link0.add_geom(
        type=G.mjGEOM_CAPSULE, size=[0.06, 0.2, 0], pos=[0, 0, 0.2], rgba=[0.2, 0.6, 0.9, 1]
    )
    link1 = link0.add_body(name="link1", pos=[0, 0, 0.4])
    link1.add_joint(name="j1", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 1, 0])
    link1.add_geom(
        type=G.mjGEOM_CYLINDER, size=[0.05, 0.2, 0], pos=[0, 0, 0.2], rgba=[0.2, 0.8, 0.4, 1]
    )
    link1.add_geom(
        type=G.mjGEOM_SPHERE, size=[0.08, 0, 0], pos=[0, 0, 0.45], rgba=[0.9, 0.9, 0.2, 1]
    )
    cube = world.add_body(name="cube", pos=[0.5, 0, 0.025])
    cube.add_freejoint()
    cube.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.025] * 3, rgba=[0.9, 0.5, 0.1, 1])
    return spec.compile()


def swing_qpos(model: mujoco.MjModel, n_frames: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """A made-up swing: (time_s (T,), qpos (T, nq)) with both hinges moving and the cube flying."""
    t = np.linspace(0.0, 2.0, n_frames)
    qpos = np.tile(model.qpos0, (n_frames, 1))
    qpos[:, 0] = 0.8 * np.sin(2 * np.pi * t / 2.0)
    qpos[:, 1] = 0.6 * np.sin(2 * np.pi * t / 1.0)
    qpos[:, 2] = 0.5 + 0.5 * t
    qpos[:, 4] = 0.025 + 0.5 * t * (2.0 - t)
    return t, qpos
