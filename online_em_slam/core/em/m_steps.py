"""The M-step piece ``em.m_step`` selects (the interface: step.py ``MStep``)."""
from __future__ import annotations

import numpy as np

from ..config import SlamConfig
from .complete import CompleteDataEM
from .observed import ObservedInformationEM
from .step import MStep


def make_m_step(config: SlamConfig, initial_pose: np.ndarray, rng: np.random.Generator) -> MStep:
    """The M-step piece selected by ``em.m_step``."""
    if config.em.m_step == "observed":
        return ObservedInformationEM(config, initial_pose)
    return CompleteDataEM(config, config.filter.num_particles, rng)
