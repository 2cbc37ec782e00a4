"""viser 3D view of the arm: draws the simulator's MuJoCo model and replays trajectories."""

from app.viz.scene import BodyPoses, GeomShape, arm_geoms, body_poses, draw_arm, pose_arm
from app.viz.server import Replay, VizServer, frame_at

__all__ = [
    "BodyPoses",
    "GeomShape",
    "Replay",
    "VizServer",
    "arm_geoms",
    "body_poses",
    "draw_arm",
    "frame_at",
    "pose_arm",
]
