"""Tasks: actions, observations, reward, episode end and reset for a robot.

Importing the package registers the Gymnasium ids (``MujocoRL/...``, see
:mod:`tasks.gym_env`), so ``import tasks`` at the top of a script makes them in
that process and in its subprocess workers.
"""

import robots  # noqa: F401  (a headless GL backend is chosen before dm_control loads)
from tasks import gym_env  # noqa: F401,E402  (registers the Gymnasium ids)
