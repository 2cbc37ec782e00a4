"""Task objectives measured on the robot, from the tip tracker's stream."""

from __future__ import annotations

import numpy as np

from app.workers.drivers.base import TipTracking

SMOOTH_SAMPLES = 3


def tip_speed_from_tracking(
    tracking: TipTracking, *, smooth_samples: int = SMOOTH_SAMPLES
) -> float:
    """The tip-speed objective: the largest tracked tip speed over the trial, m/s.

    The tracker's velocity (T, 3) is averaged over `smooth_samples` consecutive samples
    (about 33 ms at 90 Hz) before taking the largest norm, so one noisy sample cannot set the
    record. Raises ValueError when the stream is too short to measure anything.
    """
    vel = np.asarray(tracking.tip_vel_m_s, dtype=np.float64)
    if vel.ndim != 2 or vel.shape[1] != 3:
        raise ValueError(f"tip velocity must have shape (T, 3), got {vel.shape}")
    if vel.shape[0] < smooth_samples:
        raise ValueError(
            f"tracking stream has {vel.shape[0]} samples, need at least {smooth_samples}"
        )
    if not np.all(np.isfinite(vel)):
        raise ValueError("tracking stream holds non-finite velocities")
    kernel = np.ones(smooth_samples) / smooth_samples
    smooth = np.stack([np.convolve(vel[:, k], kernel, mode="valid") for k in range(3)], axis=1)
    return float(np.linalg.norm(smooth, axis=1).max())
