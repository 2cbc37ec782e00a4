"""The viser 3D view: geometry and poses from the simulator's model, per-tab views."""

from __future__ import annotations

import re
import time
from typing import Any

import mujoco
import numpy as np
import pytest

from app.sim import build_model
from app.viz import Replay, VizServer, arm_geoms, body_poses, frame_at, instance_poses
from app.viz.scene import capsule_mesh, cylinder_mesh


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=np.float64))
    return m.reshape(3, 3)


def _bent_qpos(model: mujoco.MjModel, n_frames: int, seed: int = 0) -> np.ndarray:
    """(T, nq): the rest pose with every hinge bent by a random, smoothly varying angle."""
    rng = np.random.default_rng(seed)
    qpos = np.tile(model.qpos0, (n_frames, 1))
    hinges = [
        model.jnt_qposadr[j]
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
    ]
    amp = rng.uniform(-0.08, 0.08, size=len(hinges))
    for t in range(n_frames):
        qpos[t, hinges] = amp * np.sin(2 * np.pi * t / n_frames + np.arange(len(hinges)))
    return qpos


def test_geoms_drawn_from_body_poses_land_where_mujoco_puts_them() -> None:
    """Body pose ∘ geom offset (what viser composes) equals MuJoCo's own geom_xpos/xmat."""
    model = build_model("throw")
    qpos = _bent_qpos(model, 5)
    poses = body_poses(model, qpos)
    data = mujoco.MjData(model)
    shapes = arm_geoms(model)
    ids = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, s.name): s for s in shapes}
    assert len(ids) == len(shapes)
    for t in (0, 3):
        data.qpos[:] = qpos[t]
        mujoco.mj_forward(model, data)
        for g, shape in ids.items():
            b = shape.body_id
            rot = _quat_to_mat(poses.quat_wxyz[t, b])
            pos = poses.pos_m[t, b] + rot @ np.asarray(shape.pos_m)
            mat = rot @ _quat_to_mat(np.asarray(shape.quat_wxyz))
            np.testing.assert_allclose(pos, data.geom_xpos[g], atol=1e-9)
            np.testing.assert_allclose(mat, data.geom_xmat[g].reshape(3, 3), atol=1e-9)
    world, base = 0, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "base")
    tip_disk = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "j2_disk9")
    assert not poses.moving[world] and not poses.moving[base]
    assert poses.moving[tip_disk]


def test_batched_disk_poses_match_mujoco() -> None:
    """The disks, drawn as one batched mesh per look, sit where MuJoCo puts each disk geom."""
    model = build_model("hammer")
    qpos = _bent_qpos(model, 4, seed=3)
    poses = body_poses(model, qpos)
    disks = [s for s in arm_geoms(model) if s.kind == "cylinder" and poses.moving[s.body_id]]
    assert len(disks) == 29  # joint 0's first disk sits on the base and never moves
    pos, quat = instance_poses(
        poses,
        np.array([s.body_id for s in disks]),
        np.array([s.pos_m for s in disks]),
        np.array([s.quat_wxyz for s in disks]),
    )
    data = mujoco.MjData(model)
    for t in range(4):
        data.qpos[:] = qpos[t]
        mujoco.mj_forward(model, data)
        for i, s in enumerate(disks):
            g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, s.name)
            np.testing.assert_allclose(pos[t, i], data.geom_xpos[g], atol=1e-9)
            mat = _quat_to_mat(quat[t, i])
            np.testing.assert_allclose(mat, data.geom_xmat[g].reshape(3, 3), atol=1e-9)


def test_cylinder_mesh_is_closed_and_sized() -> None:
    verts, faces = cylinder_mesh(0.125, 0.005, segments=12)
    radial = np.hypot(verts[:, 0], verts[:, 1]).astype(float)
    rim = radial > 1e-9  # all but the two cap centres
    assert rim.sum() == 48 and radial[rim] == pytest.approx(np.full(48, 0.125))
    # the caps have their own rim vertices: no vertex is shared by a side and a cap face
    tri = verts[faces].astype(float)
    on_cap = np.ptp(tri[:, :, 2], axis=1) < 1e-9
    assert not set(faces[on_cap].ravel().tolist()) & set(faces[~on_cap].ravel().tolist())
    assert np.unique(np.round(verts[:, 2].astype(float), 6)).tolist() == [-0.005, 0.005]
    # closed (caps and side have their own rim copies): every edge, by position, is shared
    # by exactly two faces
    pos = [tuple(np.round(v, 6)) for v in verts.astype(float)]
    edges: dict[tuple[Any, Any], int] = {}
    for f in faces:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            key = tuple(sorted((pos[a], pos[b])))
            edges[key] = edges.get(key, 0) + 1
    assert set(edges.values()) == {2}
    # outward: each face's normal points away from the centre
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("ij,ij->i", normal, tri.mean(axis=1)) > 0)


@pytest.mark.parametrize(
    ("task", "expected"),
    [
        ("throw", {"cube", "gripper"}),
        ("hammer", {"hammer"}),
        ("tip_speed", set()),
    ],
)
def test_every_task_draws_arm_floor_and_its_objects(task: str, expected: set[str]) -> None:
    """30 disks, two links, the floor, and the task's tip load / object / plate."""
    model = build_model(task)
    shapes = arm_geoms(model)
    bodies = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, s.body_id) for s in shapes}
    disks = {b for b in bodies if b and "disk" in b}
    assert len(disks) == 30
    assert {"base", "link0", "link1"} <= bodies
    assert expected <= bodies
    assert any(s.kind == "plane" for s in shapes), "no floor"
    others = {"cube", "gripper", "hammer"} - expected
    assert not (others & bodies), f"{task} draws another task's objects: {others & bodies}"
    if task == "hammer":
        ball = [s for s in shapes if s.kind == "sphere" and s.body_id == model.nbody - 1]
        assert ball and ball[0].size_m[0] == pytest.approx(0.08)
        plates = [s for s in shapes if s.kind == "cylinder" and s.size_m[0] == pytest.approx(0.25)]
        assert plates, "no force plate"
        assert plates[0].pos_m[:2] == pytest.approx((-0.5, 0.5))


def test_capsule_mesh_is_a_closed_capsule_along_z() -> None:
    verts, faces = capsule_mesh(0.06, 0.1, segments=16, rings=5)
    radial = np.hypot(verts[:, 0], verts[:, 1])
    axis_z = np.clip(verts[:, 2], -0.1, 0.1)
    dist = np.sqrt(radial**2 + (verts[:, 2] - axis_z) ** 2)
    np.testing.assert_allclose(dist, 0.06, atol=1e-6)
    assert verts[:, 2].min() == pytest.approx(-0.16) and verts[:, 2].max() == pytest.approx(0.16)
    assert faces.min() == 0 and faces.max() == len(verts) - 1


def test_frame_at_clamps_to_the_replay() -> None:
    t = np.array([0.0, 0.1, 0.2, 0.3])
    assert [frame_at(t, x) for x in (-1.0, 0.0, 0.15, 0.3, 9.0)] == [0, 0, 1, 3, 3]


def test_add_view_refuses_motion_that_does_not_fit_the_model() -> None:
    viz = VizServer(port=0)
    model = build_model("tip_speed")
    t = np.linspace(0.0, 1.0, 4)
    good = np.tile(model.qpos0, (4, 1))
    with pytest.raises(ValueError, match=r"qpos must have shape \(T, 54\)"):
        viz.add_view(Replay("tip_speed", t, good[:, :10], "short"))
    with pytest.raises(ValueError, match="NaN"):
        bad = good.copy()
        bad[2, 5] = np.nan
        viz.add_view(Replay("tip_speed", t, bad, "nan"))
    with pytest.raises(ValueError, match="time_s must increase"):
        viz.add_view(Replay("tip_speed", t[::-1], good, "backwards"))
    key = viz.add_view(Replay("tip_speed", t, good, "ok"))
    assert viz.has_view(key) and not viz.has_view("nope")


@pytest.mark.browser
@pytest.mark.slow
def test_each_tab_gets_its_own_view_and_playback(browser: Any) -> None:
    """Two tabs on two views, one on an expired key: own scenes, own play state, a message."""
    viz = VizServer(host="127.0.0.1", port=0)
    viz.start()
    try:
        model = build_model("tip_speed")
        t = np.linspace(0.0, 20.0, 50)  # 80 s at the default 0.25×: still playing when checked
        key_a = viz.add_view(
            Replay("tip_speed", t, _bent_qpos(model, 50), "trial A"),
            Replay("tip_speed", t[:30], _bent_qpos(model, 30, seed=2), "trial C"),
        )
        key_b = viz.add_view(Replay("tip_speed", t, _bent_qpos(model, 50, seed=1), "trial B"))
        base = f"http://127.0.0.1:{viz.port}"
        # Small tabs: software WebGL on a shared CI machine is slow.
        context = browser.new_context(viewport={"width": 480, "height": 360})
        tabs = {}
        for name, key in (("A", key_a), ("B", key_b), ("gone", "expired-key")):
            tab = context.new_page()
            tab.goto(f"{base}/?websocket=ws://127.0.0.1:{viz.port}/view/{key}")
            tabs[name] = tab
        tabs["A"].get_by_text("trial A").wait_for(timeout=60_000)
        tabs["B"].get_by_text("trial B").wait_for(timeout=60_000)
        tabs["gone"].get_by_text("No replay here").wait_for(timeout=60_000)
        assert tabs["A"].get_by_text("trial B").count() == 0
        tabs["A"].get_by_text("show overlay").wait_for()  # the second, see-through arm
        assert tabs["B"].get_by_text("show overlay").count() == 0
        assert viz.sessions_for(key_a) == 1 and viz.sessions_for(key_b) == 1

        # dispatch, not click: a click waits for a settled frame, which a busy software
        # renderer may not give for a long time.
        tabs["A"].get_by_role("button", name="Play").dispatch_event("click")
        deadline = time.monotonic() + 90
        moved = 0.0
        while time.monotonic() < deadline and moved <= 0.0:
            time.sleep(0.5)
            [(_, moved)] = viz.playback(key_a)
        assert moved > 0.0, "tab A's replay did not advance"
        assert viz.playback(key_b) == [(False, 0.0)], "tab B moved with tab A"
        tabs["A"].get_by_role("button", name="Pause").wait_for(timeout=60_000)
        assert tabs["B"].get_by_role("button", name="Play").is_visible()

        html = context.request.get(base + "/").text()
        assert "<script" in html and not re.search(r"<(script|link)[^>]+(src|href)=\"https?:", html)
        context.close()
    finally:
        viz.stop()
