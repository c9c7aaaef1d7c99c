"""Update rules for the conformal variable lambda.

Sign convention (whole toolkit, one for every rule)
---------------------------------------------------
A *smaller* lambda is *more conservative*: the decision family's loss is (weakly)
increasing in lambda. Every rule here therefore moves lambda **down after a loss above
the target epsilon and up after a loss below it**; in its simplest form

    lambda_{k+1} = lambda_k + eta (epsilon - l_k).

In the flagship (conformal CBF controller) lambda is the slack added to every barrier
constraint, so a larger lambda loosens the constraints (less safe, faster); in online
conformal prediction (Gibbs & Candès 2021) lambda is the nominal miscoverage level
alpha_t, so a larger lambda gives a smaller prediction set; in the CDT factory example
lambda is the machine speed. Rules written for the opposite convention (the PID paper
tracks a quantile q with q <- q + eta (err - alpha)) are stated here with lambda = -q.

Clipping
--------
Every rule accepts ``lambda_min`` / ``lambda_max`` and clips the lambda it returns into
that interval (counted in ``n_clipped_``).
Clipping changes the exact identities below: the upper clip only lowers the average
loss bound, the lower clip keeps the Theorem-2 bound as long as
``lambda_min <= lambda_safe - eta`` (then it never acts under the theorem's assumption).

Guarantee kinds (``UpdateRule.capabilities.guarantee``)
------------------------------------------
``"identity"``       fixed step: mean(l) = eps + (lambda_1 - lambda_{K+1}) / (eta K) exactly,
                     and the Theorem-2 bound when lambda_safe is known.
``"step_identity"``  variable step eta_k: sum_k eta_k (eps - l_k) = lambda_{K+1} - lambda_1
                     exactly, and a long-run bound on |mean(l) - eps|.
``"long_run"``       a long-run bound on |mean(l) - eps| under the stated assumptions.
``"none"``           no finite-sample statement computed by the monitor.
"""

from .aci import ACIRule
from .base import StepRule
from .decaying_eta import DecayingEtaRule
from .dtaci import DtACIRule
from .fixed_eta import FixedEtaRule
from .pid import PIDRule

__all__ = ["ACIRule", "DecayingEtaRule", "DtACIRule", "FixedEtaRule", "PIDRule", "StepRule"]
