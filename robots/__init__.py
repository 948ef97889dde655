"""Robots: MJCF models with their actuators and sensors; no rewards."""

import os

# Headless by default: dm_control picks a GL backend when first imported.
os.environ.setdefault("MUJOCO_GL", "egl")
