"""Velocity safety-filter backends, one module per solver (qpsolvers style).

==========  ==================================================  =====================
name        backend                                             class
==========  ==================================================  =====================
``qp``      piqp (interior point; general QP, the reference)    :class:`QPSafetyFilter`
``exact2d`` exact incremental 2-D solver, compiled with numba   :class:`Exact2DSafetyFilter`
==========  ==================================================  =====================

Both solve the same problem (:mod:`conformal_control.families.cbf.filters.base`) with the same
fallbacks (:mod:`conformal_control.families.cbf.fallbacks`) and report the same counters.
"""

from .base import VelocityFilter
from .exact2d import Exact2DSafetyFilter
from .piqp import QPSafetyFilter

__all__ = ["Exact2DSafetyFilter", "QPSafetyFilter", "VelocityFilter"]
