"""Sampling-based model-predictive control as conformal decision families.

=================  ===============================================================
``mpc``            :class:`SamplingMPC`: sampled plans, safe distance
                   ``d_c + margin - lambda`` to the predictions (the CDT conformal
                   controller when lambda is learned: ``cc_mpc``)
``acp_mpc``        :class:`ACPMPC`: adaptive conformal prediction regions per plan step
                   (Dixit et al. 2023), lambda = their miscoverage level
``ecp_mpc``        :class:`ECPMPC`: egocentric conformal regions per candidate position
                   (Shin et al. 2025), lambda = their miscoverage level
=================  ===============================================================
"""

from .acp import ACPMPC, ACPMPCIntervalRecord, PlanMiscoverageLoss
from .controller import FALLBACKS, MPCIntervalRecord, Plan, SamplingMPC
from .ecp import ECPMPC, ECPMPCIntervalRecord, EgocentricMiscoverageLoss
from .kernels import evaluate
from .settings import Costs, Limits, Sampling
from .stepwise import StepwiseMPC

__all__ = [
    "ACPMPC",
    "ECPMPC",
    "FALLBACKS",
    "ACPMPCIntervalRecord",
    "Costs",
    "ECPMPCIntervalRecord",
    "EgocentricMiscoverageLoss",
    "Limits",
    "MPCIntervalRecord",
    "Plan",
    "PlanMiscoverageLoss",
    "Sampling",
    "SamplingMPC",
    "StepwiseMPC",
    "evaluate",
]
