"""n-step returns for one member's copies (Sutton & Barto, ch. 7; Rainbow's multi-step target).

Each copy keeps its last (up to ``n``) transitions. A transition leaves the queue as one
replay row once ``n`` rewards follow it, or when its episode ends::

    R = r_t + gamma r_(t+1) + ... + gamma^(k-1) r_(t+k-1),   k = n, or fewer at an episode's end
    target = R + gamma^k max_a Q(s_(t+k), a)   (no bootstrap if s_(t+k) is terminal)

A truncated episode (the time limit) bootstraps from its last next observation, a
terminated one does not. The rows carry ``steps`` = k for the target's discount.
"""

from __future__ import annotations

import torch

from learners.transitions import Transitions


class NStep:
    """The queues of ``copies`` copies of one member (oldest first in each)."""

    def __init__(self, n: int, copies: int, n_obs: int, gamma: float) -> None:
        self.n, self.gamma = int(n), float(gamma)
        self.obs = torch.zeros(copies, n, n_obs)
        self.action = torch.zeros(copies, n, dtype=torch.int64)
        self.reward = torch.zeros(copies, n)
        self.count = torch.zeros(copies, dtype=torch.int64)

    def push(self, batch: Transitions, done: torch.Tensor) -> Transitions | None:
        """Adds one step of every copy (``batch``: a transition per copy; ``done``: its episode
        ended, terminated or truncated); the transitions that leave their queues, as rows
        with ``steps``, copy by copy, oldest first (None if none)."""
        copies = torch.arange(len(self.count))
        self.obs[copies, self.count] = batch.observation
        self.action[copies, self.count] = batch.action.reshape(-1)
        self.reward[copies, self.count] = batch.reward.reshape(-1)
        self.count += 1
        done = done.reshape(-1)
        slot = torch.arange(self.n)
        held = slot < self.count.unsqueeze(1)  # [copies, n]: the queued entries
        full = (self.count == self.n) & ~done  # a full queue: its oldest leaves
        leaving = (held & done.unsqueeze(1)) | ((slot == 0).unsqueeze(0) & full.unsqueeze(1))
        returns = torch.zeros_like(self.reward)
        later = torch.zeros(len(self.count))
        for j in reversed(range(self.n)):  # R_j = r_j + gamma R_(j+1), over the held entries
            later = torch.where(held[:, j], self.reward[:, j] + self.gamma * later, later)
            returns[:, j] = later
        out = None
        if leaving.any():
            c, j = leaving.nonzero(as_tuple=True)
            out = Transitions(self.obs[c, j], self.action[c, j].unsqueeze(1), returns[c, j].unsqueeze(1),
                              batch.next_observation[c], batch.terminated[c] & done[c].unsqueeze(1),
                              (self.count[c] - j).unsqueeze(1).to(self.reward.dtype))
        if full.any():  # the oldest left: the rest move up one place
            for queue in (self.obs, self.action, self.reward):
                queue[full] = torch.roll(queue[full], -1, dims=1)
            self.count[full] -= 1
        self.count[done] = 0
        return out

    def state_dict(self) -> dict:
        return {"obs": self.obs.clone(), "action": self.action.clone(), "reward": self.reward.clone(),
                "count": self.count.clone()}

    def load_state_dict(self, state: dict) -> None:
        for key in ("obs", "action", "reward", "count"):
            getattr(self, key).copy_(state[key])
