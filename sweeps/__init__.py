"""Many runs: a sweep's folder and state, the comparison of its jobs, statistics, tuning.

Imports point down only: ``sweeps`` uses ``runs`` and the layers below it; the
entry points (``train.py``, ``compare.py``, the Hydra plugins) use ``sweeps``.
"""
