"""Seeding: one call fixes the global random streams a run draws from."""

from __future__ import annotations

import random

import numpy as np
import torch


def seed_everything(seed: int) -> torch.Generator:
    """Seeds torch, numpy and Python's ``random`` globals; returns a dedicated torch generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))
    random.seed(seed)
    gen = torch.Generator()
    gen.manual_seed(seed)
    return gen

