"""What the 3D view costs the server, next to the simulator it draws.

    python benchmarks/dashboard_viz.py --task throw --repeats 3

1. Building a view: ``VizServer.add_view`` (forward kinematics of every recorded frame) on
   the qpos of one 5 s rollout, against that rollout itself (``app.sim.rollout``), same run.
2. Playing it: one replay frame (posing every moving body of the arm through viser, as the
   ticker does for a tab at 30 Hz), against raw ``mujoco.mj_kinematics`` for that frame; and
   the share of one core a playing tab takes at 30 frames/s.

Median of the repeats. No browser is connected: the frame cost is the server's side (building
and queueing viser's messages), which is what the server pays per tab.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import mujoco
import numpy as np

from app.policy import Policy, PressureLimits
from app.sim import build_model, rollout
from app.viz import Replay, VizServer, body_poses, draw_arm, pose_arm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="throw", choices=["throw", "hammer", "tip_speed"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=300, help="replay frames timed per repeat")
    args = parser.parse_args()

    policy = Policy(7, with_release=args.task == "throw", limits=PressureLimits())
    theta = np.random.default_rng(0).uniform(size=policy.dim)
    decoded = policy.decode(theta)

    rollout_s, build_s = [], []
    viz = VizServer(host="127.0.0.1", port=0)
    viz.start()
    try:
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = rollout(
                args.task,
                decoded.pressure_schedule_pa,
                release_step=decoded.release_step,
                record_qpos=True,
            )
            rollout_s.append(time.perf_counter() - t0)
            replay = Replay(args.task, res.trajectory.time_s, res.trajectory.qpos, "bench")
            t0 = time.perf_counter()
            viz.add_view(replay)
            build_s.append(time.perf_counter() - t0)

        model = build_model(args.task)
        qpos = np.asarray(res.trajectory.qpos)
        poses = body_poses(model, qpos)
        handles = draw_arm(viz._server.scene, "/bench", model, poses)
        data = mujoco.MjData(model)
        frame_s, kin_s = [], []
        n = min(args.frames, len(qpos))
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for f in range(n):
                with viz._server.atomic():  # as the ticker does: one flush per frame
                    pose_arm(handles, poses, f)
            frame_s.append((time.perf_counter() - t0) / n)
            t0 = time.perf_counter()
            for f in range(n):
                data.qpos[:] = qpos[f]
                mujoco.mj_kinematics(model, data)
            kin_s.append((time.perf_counter() - t0) / n)
    finally:
        viz.stop()

    out = {
        "task": args.task,
        "frames_recorded": len(qpos),
        "moving_bodies": int(poses.moving.sum()),
        "nodes_posed_per_frame": len(handles.bodies) + len(handles.batches),
        "rollout_s": statistics.median(rollout_s),
        "add_view_s": statistics.median(build_s),
        "add_view_over_rollout": statistics.median(build_s) / statistics.median(rollout_s),
        "frame_ms": 1e3 * statistics.median(frame_s),
        "mj_kinematics_ms": 1e3 * statistics.median(kin_s),
        "frame_over_kinematics": statistics.median(frame_s) / statistics.median(kin_s),
        "core_share_per_playing_tab_at_30hz": 30.0 * statistics.median(frame_s),
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
