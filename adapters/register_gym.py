"""Importing this module registers the ``MujocoRL/...`` Gymnasium ids (see :mod:`adapters.gym_env`).

It is the module Gymnasium and the tools around it import by name::

    gymnasium.make("adapters.register_gym:MujocoRL/CartPoleStayUp-v0")
    python -m rl_zoo3.train --gym-packages adapters.register_gym --env MujocoRL/CartPoleStayUp-v0

Nothing else registers the ids: importing ``tasks`` or ``runs`` does not.
"""

from adapters.gym_env import register_envs

IDS = register_envs()
