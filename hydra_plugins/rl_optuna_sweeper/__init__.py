"""Hydra plugin: the ``optuna`` sweeper (``hydra/sweeper=optuna``), see :mod:`.optuna_sweeper`."""
