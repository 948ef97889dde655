"""Robots: MJCF models with their actuators and sensors; no rewards."""

import logging
import os

# Headless by default: dm_control picks a GL backend when first imported.
os.environ.setdefault("MUJOCO_GL", "egl")
# PyOpenGL says at INFO, when dm_control first imports it, that its optional C accelerator
# is missing; imported inside a run (after Hydra set up logging), that line would land on
# the console and in train.log.
logging.getLogger("OpenGL.acceleratesupport").setLevel(logging.WARNING)
