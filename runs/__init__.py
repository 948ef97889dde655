"""One run: building it from a config, its folder, console, files, checkpoints, verdict.

Imports point down only: ``runs`` uses ``learners``, ``tasks``, ``robots`` and
``params``; it never imports ``sweeps`` or an entry point.
"""

import robots  # noqa: F401,E402  (headless GL, MUJOCO_GL=egl, before anything imports MuJoCo)
