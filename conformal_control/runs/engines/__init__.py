"""Backends of the conformal loop: how an episode's control instants are executed.

* :mod:`~conformal_control.runs.engines.loop` -- the generic
  :class:`~conformal_control.core.loop.ConformalLoop`, one chain of Python calls per control
  instant, for any configuration;
* :mod:`~conformal_control.runs.engines.batch` -- the compiled lockstep engine (one compiled
  call per interval, many episodes at once) with its kernels
  (:mod:`~conformal_control.runs.engines.interval`, :mod:`~conformal_control.runs.engines.kernels`,
  :mod:`~conformal_control.runs.engines.gap_kernels`).

Both give the same result; :func:`~conformal_control.runs.engines.batch.run_single` picks one
(for :func:`conformal_control.runs.episode.run_episode` and :func:`conformal_control.run`) with
``engine=``.
"""
