"""Hydra plugin: the ``seeds`` launcher (``hydra/launcher=seeds``), see :mod:`.seed_launcher`."""
