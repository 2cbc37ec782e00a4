"""viser 3D view of the arm: draws the simulator's MuJoCo model and replays trajectories."""

from app.viz.scene import (
    ArmHandles,
    BodyPoses,
    GeomShape,
    arm_geoms,
    body_poses,
    draw_arm,
    instance_poses,
    pose_arm,
)
from app.viz.server import Replay, VizServer, frame_at

__all__ = [
    "ArmHandles",
    "BodyPoses",
    "GeomShape",
    "Replay",
    "VizServer",
    "arm_geoms",
    "body_poses",
    "draw_arm",
    "frame_at",
    "instance_poses",
    "pose_arm",
]
