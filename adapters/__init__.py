"""Adapters to other tools: Gymnasium ids for every robot's default task (:mod:`adapters.gym_env`,
registered by importing :mod:`adapters.register_gym`) and rl-baselines3-zoo's scripts with
them (:mod:`adapters.zoo`)."""
