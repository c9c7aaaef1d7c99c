"""Lockstep batch engine: many episodes of the flagship at once, the same metrics.

:func:`~conformal_control.runs.episode.run_episode`'s generic loop runs one episode as a chain of
Python calls per control instant (environment, controller, filter, plant). :func:`run_batch`
runs many: every
episode of a batch advances by one interval per iteration, and the work of an iteration is
done for all of them together -- ONE compiled call for every control instant of the
interval (:func:`~conformal_control.runs.engines.interval.run_interval`: reference, the exact
2-D filter's fused APF step, plant, goal check, frame clock and log), compiled loops for
the replay bookkeeping (:mod:`~conformal_control.runs.engines.kernels`), and, at sampling
times, ONE call of the predictor, the interpolation, the constraint and the loss on the
agents of every episode at that sampling time laid side by side (these are computed agent
by agent, so one call on the concatenation is the same arithmetic as one call per
episode). One episode runs through :func:`run_single`, the engine choice that
:func:`run_episode` and :func:`conformal_control.run` both make: this engine when it runs
the configuration (keeping the per-instant steps and the animation record too), else the
generic loop.

The metrics are those of :func:`run_episode`, exactly: every episode is built by
:func:`~conformal_control.runs.build.build_flagship` (same parameter resolution, same
validation, same errors), its lambda is updated by its own update rule through its own
:class:`~conformal_control.core.monitor.GuaranteeMonitor`, its counters are written into the
same learned attributes the per-episode loop fills, and it is measured by the same code.
The per-instant arithmetic is written to round the same way (``tests/runs/engines/test_batch.py``
checks every metric against :func:`run_episode`). The wall time of the control loop
(``wall_s``) is the episode's share of the batch's: each iteration's time divided among
the episodes it advanced.

Supported (:func:`supports` says why not otherwise, so a caller can fall back to
:func:`run_episode`): replayed crowds, and the reactive ``social_force``, ``orca`` and
``mixed`` crowds without noise (:mod:`~conformal_control.runs.engines.reactive`: each episode's
crowd walks through the interval's control instants after its robot, one compiled call
per instant for all of them); any registered predictor; the ``cbf`` family and the
``acp`` family (adaptive conformal prediction regions); the APF barrier; the exact 2-D
filter with any registered fallback (``lambda_search``, ``brake`` and ``hold`` are decided
by the compiled step; any other, e.g. ``relax``, by the episode's own fallback object on the
compiled step's rows: the engine pauses that episode at that instant, lets the fallback
decide in Python and runs on); the attractive-field reference; the velocity-tracking plant;
the ``cbf_gap``, ``collision``, ``distance_shortfall`` or ``acp_miscoverage`` loss; any
registered update rule, learning or not. Roles are given by name (an instance would be
shared by every episode).

The ``acp`` family runs its own per-interval code (scoring its past predictions, sorting
their errors, the regions' radii at the interval's lambda: its ``begin_interval`` and
``_inflation``) on the episode's own controller, and the engine runs the interval's control
instants compiled with the barrier's collision distance raised per horizon step, as
:meth:`ACPController.decide <conformal_control.families.cbf.acp.ACPController.decide>` sets up the
compiled step; its miscoverage loss scores the interval's record with its own code.

What runs compiled and what runs through the episode's own objects: the constant-velocity
and the oracle predictor are compiled (above), and so are the predictor shifts of either
(``delayed``, ``noisy``, ``scaled``, ``dropout``, :mod:`~conformal_control.predictors.shift`)
and the ``recorded`` predictor (the forecasts of a predictions file, the benchmark's
``learned`` shift: each episode's slice of the file is packed into the batch and replayed
by :mod:`~conformal_control.runs.engines.recorded_kernels`, its constant-velocity fallback
compiled with it; with another fallback, on a scene the file does not cover or with
agent ids that are not integers it is called as it is); any other predictor is called at each
sampling time on the query the episode's environment builds
(:meth:`~conformal_control.world.replay.ReplayEnvironment.sense`), through the
controller's own ``begin_interval`` (sanitising, counters, interpolation, the same
:class:`~conformal_control.families.cbf.controller.PredictorError`), and its interpolated
predictions are copied into the batch. The gap loss is compiled; the ``collision`` and
``distance_shortfall`` losses are the loss objects themselves, called on the interval's
record and on the truth the environment reveals. The rule is the episode's own; a rule that
evaluates the interval's loss at other lambdas (``uses_loss_function``, e.g. ``dtaci``)
receives the loss as a function of lambda, as
:class:`~conformal_control.core.loop.ConformalStepper` hands it (for the gap loss
``s(max_gap + lambda)``: the gaps do not depend on lambda, and
:class:`~conformal_control.families.cbf.loss.CBFGapLoss` adds lambda to their maximum).

Memory: at most ``batch_size`` episodes are alive at a time; a finished episode's slot is
refilled from ``scenes`` (consumed lazily: pass a generator to keep only the live scenes in
memory) at the next common sampling time. With ``output="metrics"`` (default) only the
:class:`~conformal_control.runs.results.metrics.EpisodeMetrics` are kept; ``output="results"``
keeps an :class:`~conformal_control.runs.results.episode.EpisodeResult` per episode (scene, config,
intervals, per-frame trajectory, the loop's result; no per-instant ``steps`` and no
animation record).

The engine is four modules: :mod:`.engine` (the lockstep loop: :class:`Engine`,
:func:`run_batch`, :func:`iter_batch`, :func:`run_single`), :mod:`.pool` (the slots' arrays
and the compiled steps run on them), :mod:`.episode` (what is done per episode in Python:
building and loading it into a slot, its own objects' part of an interval, measuring it)
and :mod:`.supports` (what the engine runs: :func:`supports`, the compiled counterparts it
has kernels for, how it reads a built episode's parts).
"""

from .engine import Engine, iter_batch, run_batch, run_single
from .supports import ANY_NAME_ROLES, COMPILED_FALLBACKS, KERNELS, as_run_spec, supports

__all__ = [
    "ANY_NAME_ROLES",
    "COMPILED_FALLBACKS",
    "KERNELS",
    "Engine",
    "as_run_spec",
    "iter_batch",
    "run_batch",
    "run_single",
    "supports",
]
