"""The arm as viser scene nodes, drawn from the compiled MuJoCo model the simulator uses.

Every visible geom of the compiled model becomes one viser primitive under its body's frame
(``/<root>/body_<id>``); a replay then only moves the body frames, with poses from
``mujoco.mj_kinematics`` on the recorded ``qpos``. Nothing here knows about the arm's layout:
disks, links, tip load, cube or hammer, force plate and floor are whatever the model holds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
import trimesh
from viser.transforms import SO3

_GEOM_KINDS: dict[int, str] = {
    int(mujoco.mjtGeom.mjGEOM_PLANE): "plane",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}
FLOOR_HALF_SIZE_M = 1.5  # an infinite MuJoCo plane is drawn as a 3 m × 3 m tile


@dataclass(frozen=True)
class GeomShape:
    """One drawable geom, in its body's frame.

    Attributes:
        name: the geom's name in the model, or ``geom_<id>``.
        body_id: index of the body that carries it.
        kind: plane, sphere, capsule, ellipsoid, cylinder, box or mesh.
        size_m: (3,) MuJoCo size (half-extents / radius, half-length), m.
        pos_m: (3,) position in the body frame, m.
        quat_wxyz: (4,) orientation in the body frame.
        rgba: (4,) colour in [0, 1].
        mesh_id: index into the model's meshes when ``kind == "mesh"``, else -1.
    """

    name: str
    body_id: int
    kind: str
    size_m: tuple[float, float, float]
    pos_m: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]
    rgba: tuple[float, float, float, float]
    mesh_id: int = -1


def arm_geoms(model: mujoco.MjModel, *, max_group: int = 2) -> list[GeomShape]:
    """The model's visible geoms (group ≤ ``max_group``, alpha > 0) as :class:`GeomShape` s."""
    shapes: list[GeomShape] = []
    for g in range(model.ngeom):
        kind = _GEOM_KINDS.get(int(model.geom_type[g]))
        if kind is None or int(model.geom_group[g]) > max_group:
            continue
        mat = int(model.geom_matid[g])
        rgba = model.mat_rgba[mat] if mat >= 0 else model.geom_rgba[g]
        if float(rgba[3]) <= 0.0:
            continue
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom_{g}"
        shapes.append(
            GeomShape(
                name=name,
                body_id=int(model.geom_bodyid[g]),
                kind=kind,
                size_m=tuple(float(v) for v in model.geom_size[g]),  # type: ignore[arg-type]
                pos_m=tuple(float(v) for v in model.geom_pos[g]),  # type: ignore[arg-type]
                quat_wxyz=tuple(float(v) for v in model.geom_quat[g]),  # type: ignore[arg-type]
                rgba=tuple(float(v) for v in rgba),  # type: ignore[arg-type]
                mesh_id=int(model.geom_dataid[g]) if kind == "mesh" else -1,
            )
        )
    return shapes


@dataclass(frozen=True)
class BodyPoses:
    """Body poses over a replay.

    Attributes:
        pos_m: (T, nbody, 3) world positions, m.
        quat_wxyz: (T, nbody, 4) world orientations.
        moving: (nbody,) True for bodies whose pose changes during the replay.
    """

    pos_m: np.ndarray
    quat_wxyz: np.ndarray
    moving: np.ndarray


def body_poses(model: mujoco.MjModel, qpos: np.ndarray) -> BodyPoses:
    """Forward kinematics of every frame: qpos (T, nq) → body poses (mj_kinematics)."""
    q = np.asarray(qpos, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != model.nq:
        raise ValueError(
            f"qpos must have shape (T, {model.nq}) for this model, got {tuple(q.shape)}"
        )
    if q.shape[0] < 1:
        raise ValueError("qpos has no frames")
    if not np.all(np.isfinite(q)):
        raise ValueError("qpos holds NaN or inf")
    data = mujoco.MjData(model)
    pos = np.empty((q.shape[0], model.nbody, 3))
    quat = np.empty((q.shape[0], model.nbody, 4))
    for t in range(q.shape[0]):
        data.qpos[:] = q[t]
        mujoco.mj_kinematics(model, data)
        pos[t] = data.xpos
        quat[t] = data.xquat
    moving = (np.ptp(pos, axis=0).max(axis=1) > 1e-9) | (np.ptp(quat, axis=0).max(axis=1) > 1e-9)
    return BodyPoses(pos, quat, moving)


def capsule_mesh(
    radius_m: float, half_length_m: float, *, segments: int = 20, rings: int = 6
) -> tuple[np.ndarray, np.ndarray]:
    """A capsule along z (MuJoCo's convention), trimesh's: vertices (V, 3) m, faces (F, 3)
    int32; ``segments`` around, ``rings`` latitude steps per hemisphere."""
    mesh = trimesh.creation.capsule(
        height=2.0 * half_length_m, radius=radius_m, count=[2 * rings, segments]
    )
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32)


def cylinder_mesh(
    radius_m: float, half_height_m: float, *, segments: int = 28
) -> tuple[np.ndarray, np.ndarray]:
    """A closed cylinder along z centred at 0 (trimesh's): vertices (V, 3) m, faces (F, 3).

    The caps get their own copies of the rim vertices (``smooth_shade`` splits the 90° edges),
    so the viewer's smoothed normals stay radial on the side and axial on the caps (shared
    rims shade the disks pale).
    """
    mesh = trimesh.creation.cylinder(radius=radius_m, height=2.0 * half_height_m, sections=segments)
    mesh = trimesh.graph.smooth_shade(mesh, angle=np.radians(80.0))
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32)


def instance_poses(
    poses: BodyPoses, body_ids: np.ndarray, local_pos_m: np.ndarray, local_quat_wxyz: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World poses of geoms fixed in bodies, every frame: (T, N, 3) m and (T, N, 4) wxyz."""
    bpos = poses.pos_m[:, body_ids]  # (T, N, 3)
    body = SO3(poses.quat_wxyz[:, body_ids])  # (T, N)
    pos = bpos + body.apply(np.broadcast_to(local_pos_m, bpos.shape))
    local = SO3(np.broadcast_to(local_quat_wxyz, body.wxyz.shape))
    return pos, (body @ local).wxyz


def _color(rgba: tuple[float, ...], tint: tuple[int, int, int] | None) -> tuple[int, int, int]:
    rgb = np.clip(np.asarray(rgba[:3]) * 255.0, 0, 255)
    if tint is not None:
        rgb = 0.35 * rgb + 0.65 * np.asarray(tint, dtype=np.float64)
    return (int(rgb[0]), int(rgb[1]), int(rgb[2]))


def _linear_rgb(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    """sRGB → linear, 0..255: viser treats batched instance colours as linear (single meshes as
    sRGB), so without this the batched disks render pale next to the same colour unbatched."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    out = np.round(lin * 255.0).astype(int)
    return (int(out[0]), int(out[1]), int(out[2]))


@dataclass
class ArmHandles:
    """What :func:`pose_arm` moves: body frames, and batches of identical disks.

    Attributes:
        bodies: body id → viser frame handle of a moving body.
        batches: (batched-mesh handle, positions (T, N, 3), orientations (T, N, 4)) per group
            of identical cylinders on moving bodies (the continuum joints' disks), posed with
            one message each per frame instead of one per disk.
    """

    bodies: dict[int, Any]
    batches: list[tuple[Any, np.ndarray, np.ndarray]]


def draw_arm(
    scene: Any,
    root: str,
    model: mujoco.MjModel,
    poses: BodyPoses,
    *,
    frame: int = 0,
    opacity: float | None = None,
    tint: tuple[int, int, int] | None = None,
    include_static: bool = True,
) -> ArmHandles:
    """Add the model's geoms to a viser scene (server- or client-scoped) under ``root``.

    Args:
        scene: a viser ``SceneApi`` (``server.scene`` or ``client.scene``).
        root: scene path, e.g. ``/candidate``.
        model: the compiled model whose geoms are drawn.
        poses: body poses of the replay; frame ``frame`` places the bodies.
        opacity: None for opaque, else in (0, 1) (the overlaid second arm).
        tint: RGB blended over the model's colours, to tell two arms apart.
        include_static: also draw bodies that never move (floor, plate, base).

    Returns:
        the handles to pose per frame (moving bodies and disk batches).
    """
    shapes = arm_geoms(model)
    per_body: dict[int, list[GeomShape]] = {}
    for shape in shapes:
        per_body.setdefault(shape.body_id, []).append(shape)
    # Moving bodies that carry exactly one cylinder (the disks) are drawn batched by look.
    groups: dict[tuple[Any, ...], list[GeomShape]] = {}
    for b, body_shapes in per_body.items():
        if poses.moving[b] and len(body_shapes) == 1 and body_shapes[0].kind == "cylinder":
            shape = body_shapes[0]
            look = (tuple(np.round(shape.size_m, 6)), tuple(np.round(shape.rgba, 4)))
            groups.setdefault(look, []).append(shape)
    batched = {s.name for group in groups.values() if len(group) >= 2 for s in group}

    arm = ArmHandles(bodies={}, batches=[])
    for i, group in enumerate(g for g in groups.values() if len(g) >= 2):
        first = group[0]
        pos, quat = instance_poses(
            poses,
            np.array([s.body_id for s in group]),
            np.array([s.pos_m for s in group]),
            np.array([s.quat_wxyz for s in group]),
        )
        verts, faces = cylinder_mesh(first.size_m[0], first.size_m[1])
        handle = scene.add_batched_meshes_simple(
            f"{root}/disks_{i}",
            verts,
            faces,
            batched_wxyzs=quat[frame],
            batched_positions=pos[frame],
            batched_colors=_linear_rgb(_color(first.rgba, tint)),
            opacity=opacity,
            lod="off",
        )
        arm.batches.append((handle, pos, quat))

    body_nodes: dict[int, str] = {}
    for shape in shapes:
        b = shape.body_id
        if shape.name in batched or (not include_static and not poses.moving[b]):
            continue
        if b not in body_nodes:
            body_nodes[b] = f"{root}/body_{b}"
            handle = scene.add_frame(
                body_nodes[b],
                show_axes=False,
                wxyz=poses.quat_wxyz[frame, b],
                position=poses.pos_m[frame, b],
            )
            if poses.moving[b]:
                arm.bodies[b] = handle
        node = f"{body_nodes[b]}/{shape.name}"
        color = _color(shape.rgba, tint)
        alpha = opacity if opacity is not None else (shape.rgba[3] if shape.rgba[3] < 1 else None)
        common = {"wxyz": shape.quat_wxyz, "position": shape.pos_m, "opacity": alpha}
        sx, sy, sz = shape.size_m
        if shape.kind == "box":
            scene.add_box(node, color=color, dimensions=(2 * sx, 2 * sy, 2 * sz), **common)
        elif shape.kind == "plane":
            hx = sx if sx > 0 else FLOOR_HALF_SIZE_M
            hy = sy if sy > 0 else FLOOR_HALF_SIZE_M
            pos = (shape.pos_m[0], shape.pos_m[1], shape.pos_m[2] - 0.001)
            scene.add_box(
                node,
                color=color,
                dimensions=(2 * hx, 2 * hy, 0.002),
                wxyz=shape.quat_wxyz,
                position=pos,
                opacity=common["opacity"],
                cast_shadow=False,
            )
        elif shape.kind == "sphere":
            scene.add_icosphere(node, radius=sx, color=color, subdivisions=2, **common)
        elif shape.kind == "ellipsoid":
            scene.add_icosphere(
                node, radius=1.0, color=color, subdivisions=2, scale=(sx, sy, sz), **common
            )
        elif shape.kind == "cylinder":
            scene.add_cylinder(node, radius=sx, height=2 * sy, color=color, **common)
        elif shape.kind == "capsule":
            verts, faces = capsule_mesh(sx, sy)
            scene.add_mesh_simple(node, verts, faces, color=color, **common)
        elif shape.kind == "mesh":
            m = shape.mesh_id
            v0, nv = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
            f0, nf = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
            scene.add_mesh_simple(
                node,
                np.asarray(model.mesh_vert[v0 : v0 + nv], dtype=np.float32),
                np.asarray(model.mesh_face[f0 : f0 + nf], dtype=np.int32),
                color=color,
                **common,
            )
    return arm


def pose_arm(arm: ArmHandles, poses: BodyPoses, frame: int) -> None:
    """Move what :func:`draw_arm` drew to replay frame ``frame`` (clamped)."""
    f = min(max(int(frame), 0), poses.pos_m.shape[0] - 1)
    for b, handle in arm.bodies.items():
        handle.wxyz = poses.quat_wxyz[f, b]
        handle.position = poses.pos_m[f, b]
    for handle, pos, quat in arm.batches:
        handle.batched_positions = pos[f]
        handle.batched_wxyzs = quat[f]
