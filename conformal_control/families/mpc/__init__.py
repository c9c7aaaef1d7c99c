"""Sampling-based model-predictive control as conformal decision families.

========================  ===============================================================
``mpc``                   :class:`SamplingMPC`: sampled plans, safe distance
                          ``d_c + margin - lambda`` to the predictions (the CDT conformal
                          controller when lambda is learned: ``cc_mpc``)
``acp_mpc``               :class:`ACPMPC`: adaptive conformal prediction regions per plan step
                          (Dixit et al. 2023), lambda = their miscoverage level
``ecp_mpc``               :class:`ECPMPC`: egocentric conformal regions per candidate position
                          (Shin et al. 2025), lambda = their miscoverage level
``fcp_mpc``               :class:`FCPMPC`: conformalized distance fields (FCP-MPC 2026), hard
                          or soft, lambda = 1 - the multiplier of the envelope's radii
``soft_mpc``              :class:`SoftRewardMPC`: no safe distance, a reward ``-lambda`` per metre
                          of distance to the predictions (the published CC-MPC)
``interval_margin_mpc``   :class:`IntervalMarginMPC`: the safe distance ``d_c + margin -
                          lambda_j`` per pedestrian over the plan steps one interval covers,
                          ``d_c + margin`` beyond
========================  ===============================================================
"""

from .acp import ACPMPC, ACPMPCIntervalRecord, PlanMiscoverageLoss
from .controller import FALLBACKS, MPCIntervalRecord, Plan, SamplingMPC
from .ecp import ECPMPC, ECPMPCIntervalRecord, EgocentricMiscoverageLoss
from .fcp import (
    FCPMPC,
    FCPMPCIntervalRecord,
    FieldCalibration,
    FieldConstraint,
    FieldMiscoverageLoss,
)
from .interval_margin import IntervalMarginMPC
from .kernels import evaluate
from .margin import AgentMarginMiscoverageLoss, MarginMiscoverageLoss
from .settings import Costs, Limits, Sampling
from .soft import NegativeDistanceLoss, SoftRewardMPC
from .stepwise import StepwiseMPC

__all__ = [
    "ACPMPC",
    "ECPMPC",
    "FALLBACKS",
    "FCPMPC",
    "ACPMPCIntervalRecord",
    "AgentMarginMiscoverageLoss",
    "Costs",
    "ECPMPCIntervalRecord",
    "EgocentricMiscoverageLoss",
    "FCPMPCIntervalRecord",
    "FieldCalibration",
    "FieldConstraint",
    "FieldMiscoverageLoss",
    "IntervalMarginMPC",
    "Limits",
    "MPCIntervalRecord",
    "MarginMiscoverageLoss",
    "NegativeDistanceLoss",
    "Plan",
    "PlanMiscoverageLoss",
    "Sampling",
    "SamplingMPC",
    "SoftRewardMPC",
    "StepwiseMPC",
    "evaluate",
]
