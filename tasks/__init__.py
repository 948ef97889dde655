"""Tasks: actions, observations, reward, episode end and reset for a robot."""

import robots  # noqa: F401  (a headless GL backend is chosen before dm_control loads)
