"""One finished training episode, as the run's outputs report it.

:class:`~runs.run.Run` makes one :class:`Episode` per finished episode;
the metrics files, the console and the logger each read what they show from
it.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Episode:
    episode: int  # 1-based, in the order episodes finished (ties by copy index)
    env_index: int  # which copy of the batched env ran it
    reward: float  # its return
    length: int  # its steps
    terminated: bool  # ended by the task (not by a time limit or a physics divergence)
    env_steps: int  # env steps of all copies so far
    wall_s: float  # seconds since the run started, to the millisecond
    value: float  # the task's success measure for this episode
    rolling: float  # its mean over the last ``success.window`` episodes
    extra: dict = field(default_factory=dict)  # the learner's numbers (alpha, gamma, epsilon)
