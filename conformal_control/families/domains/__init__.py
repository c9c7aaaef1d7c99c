"""Decision problems other than the flagship, run through the same generic loop unchanged.

* :mod:`~conformal_control.families.domains.factory` - the CDT paper's factory toy example (lambda
  is the machine speed, the loss the fraction of defective items).
* :mod:`~conformal_control.families.domains.intervals` - online conformal prediction sets for a real
  time series (next-position discs around a registered predictor's forecasts of ETH/UCY
  pedestrians), lambda = nominal miscoverage level or minus the radius.
"""
