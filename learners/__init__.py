"""Learners: tabular Q-learning and the replay-buffer DQN family."""

import robots  # noqa: F401,E402  (headless GL, MUJOCO_GL=egl, before anything imports MuJoCo)
