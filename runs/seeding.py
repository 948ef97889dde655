"""Seeding: one call fixes the global random streams a run draws from."""

from __future__ import annotations

import numpy as np
import torch


def seed_everything(seed: int) -> torch.Generator:
    """Seeds torch and numpy globals; returns a dedicated torch generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))
    gen = torch.Generator()
    gen.manual_seed(seed)
    return gen
