"""Predictor shifts: wrappers that make any predictor worse in one controlled way.

A benchmark that only ever runs a good predictor cannot show what a controller that adapts
to prediction error is worth. Each wrapper here takes a predictor (a registered name, with
``predictor_params``, or an instance) and degrades what it sees or what it returns in one
documented way, with its parameter in the unit its name carries:

``delayed``  ``delay_s``: the forecast is made from the data as it was ``delay_s`` seconds
             ago and used as if it were current (a perception latency that is *not*
             compensated);
``noisy``    ``sigma_m``: every forecast is displaced by a Gaussian position error of
             standard deviation ``sigma_m`` per axis, one draw per agent and sampling time;
``scaled``   ``scale``: the predicted displacement from the current position is multiplied
             by ``scale`` (0 = a frozen predictor, 1 = unchanged, 2 = twice as fast);
``dropout``  ``p``, ``duration_s``: time is cut into blocks of ``duration_s`` seconds and
             each agent's detections are missing during a block with probability ``p``;
             while its current detection is missing the forecast is made from its last
             detection (not compensated, as ``delayed``).

Neutral settings return the wrapped predictor's forecast itself (``delay_s=0``,
``sigma_m=0``, ``scale=1``, ``p=0``): the run is then the same as with the wrapped predictor,
bit for bit.

Random draws are a hash of (``random_state``, scene name, frame, agent id) (SplitMix64), not
a stream: an agent's noise does not depend on which other agents are in the query or on
the order of the calls, so predicting agents together or one by one gives the same rows,
two runs with the same seed are identical, and two methods run on the same scenario see
the same noise where they sense the same agents. ``random_state=None`` means 0 (runs are
always reproducible; ``build_flagship`` passes the run's seed).

Fallbacks, all counted in ``Forecast.info``: an agent whose current position is not finite
gets a NaN forecast (``n_nonfinite_current``; the controller holds it); a delayed or dropped
agent that was not observed in the delayed data is predicted from its last observation
before the cut (``n_stale``) or, never observed then, from its first observation
(``n_unseen``), standing still.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..core.base import CompiledForm
from .base import Forecast, PredictionQuery, Predictor

__all__ = [
    "DelayedForm",
    "DelayedPredictor",
    "DropoutForm",
    "DropoutPredictor",
    "NoisyForm",
    "NoisyPredictor",
    "ScaledForm",
    "ScaledPredictor",
    "ShiftForm",
    "ShiftedPredictor",
    "hash_normal",
    "hash_uniform",
    "noise_offsets",
]

# ------------------------------------------------------------------ counter-based draws
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def _u64(x: Any) -> np.ndarray:
    """Integers (any sign) as uint64 bit patterns, at least 1-D."""
    return np.atleast_1d(np.asarray(x, dtype=np.int64)).view(np.uint64)


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser (wrapping uint64 arithmetic)."""
    with np.errstate(over="ignore"):
        x = x + _GOLDEN
        x = (x ^ (x >> np.uint64(30))) * _M1
        x = (x ^ (x >> np.uint64(27))) * _M2
    out: np.ndarray = x ^ (x >> np.uint64(31))
    return out


_MASK = (1 << 64) - 1


def _mix_int(x: int) -> int:
    """:func:`_mix` on one Python integer (the same bits, without numpy's per-call cost)."""
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def _hash(*keys: Any) -> np.ndarray:
    """One uint64 per element of the broadcast ``keys`` (integers).

    The keys are folded in order, ``h = mix(h ^ key)``; leading scalar keys (a seed, a scene,
    a frame) are folded on Python integers, the rest on the broadcast arrays."""
    h: int | None = None
    i = 0
    while i < len(keys) and np.ndim(keys[i]) == 0:
        k = int(keys[i]) & _MASK  # an int64's bit pattern, as _u64 reads it
        h = _mix_int(k if h is None else h ^ k)
        i += 1
    if i == len(keys):
        return np.array([0 if h is None else h], dtype=np.uint64)
    arrays = np.broadcast_arrays(*[_u64(k) for k in keys[i:]])
    if h is None:
        out = _mix(arrays[0].copy())
    else:
        out = _mix(np.uint64(h) ^ arrays[0])
    for a in arrays[1:]:
        out = _mix(out ^ a)
    return out


def _uniform(h: np.ndarray) -> np.ndarray:
    out: np.ndarray = (h >> np.uint64(11)).astype(np.float64) * 2.0**-53
    return out


def hash_uniform(*keys: Any) -> np.ndarray:
    """Uniform numbers in [0, 1), a deterministic function of the integer ``keys``
    (broadcast against each other): 53 bits of a SplitMix64 hash."""
    return _uniform(_hash(*keys))


def hash_normal(*keys: Any) -> np.ndarray:
    """Standard normal numbers, a deterministic function of the integer ``keys`` (Box-Muller
    on two hashed uniforms: those of the keys followed by 0 and by 1)."""
    h = _hash(*keys)
    u1 = 1.0 - _uniform(_mix(h ^ np.uint64(0)))  # (0, 1]
    u2 = _uniform(_mix(h ^ np.uint64(1)))
    out: np.ndarray = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
    return out


def scene_key(scene: str) -> int:
    """A stable integer for a scene name (CRC-32)."""
    return zlib.crc32(scene.encode("utf-8"))


# ------------------------------------------------------------------ helpers
def _number(value: Any, name: str, *, low: float = 0.0, high: float = math.inf) -> float:
    """``value`` as a finite float in [low, high], else a one-line ValueError."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(x) and low <= x <= high):
        rng = f">= {low:g}" if math.isinf(high) else f"in [{low:g}, {high:g}]"
        raise ValueError(f"{name} must be a finite number {rng}, got {value!r}")
    return x


def resolve_predictor(spec: Any, params: Mapping[str, Any] | None, role: str) -> Predictor:
    """The predictor ``spec`` names (a registered name with ``params``) or is (an instance,
    used as given)."""
    if spec is None:
        spec = "constant_velocity"
    if isinstance(spec, str):
        from ..core import registry

        out = registry.create("predictor", spec, **dict(params or {}))
        if not isinstance(out, Predictor):
            raise TypeError(f"{role}: {spec!r} is not a predictor")
        return out
    if isinstance(spec, Predictor):
        if params:
            raise ValueError(f"{role}: predictor_params apply to a predictor given by name")
        return spec
    raise ValueError(
        f"{role}: predictor must be a registered name or a Predictor instance, "
        f"got {type(spec).__name__}"
    )


def _finite_rows(x: np.ndarray) -> np.ndarray:
    """(N, T) mask of finite (x, y) samples."""
    out: np.ndarray = np.isfinite(x).all(axis=-1)
    return out


def _restart_rows(
    hist: np.ndarray, rows: np.ndarray, ends: np.ndarray
) -> tuple[np.ndarray, int, int]:
    """``hist`` (N, T, 2) with each row of ``rows`` re-ended at its sample ``ends[i]``: the
    samples up to that one are moved to the end of the row (the predictor then takes it for
    the current sample), NaN before. A row whose ``ends`` is -1 (nothing observed up to the
    cut) gets its first observation in the whole row as a one-sample history. Returns the
    new history and the numbers of stale and unseen rows."""
    out = hist.copy()
    n_stale = n_unseen = 0
    T = hist.shape[1]
    for i, j in zip(rows.tolist(), ends.tolist(), strict=True):
        row = hist[i]
        out[i] = np.nan
        if j >= 0:
            out[i, T - 1 - j :] = row[: j + 1]
            n_stale += 1
        else:
            seen = np.flatnonzero(_finite_rows(row[None])[0])
            out[i, -1] = row[seen[0]] if seen.size else row[-1]
            n_unseen += 1
    return out, n_stale, n_unseen


# ------------------------------------------------------------------ compiled forms
@dataclass(frozen=True)
class ShiftForm(CompiledForm):
    """A predictor shift as the compiled engine runs it (:meth:`ShiftedPredictor.compiled_state`):
    the kernel of the shift, its constants (validated) and the wrapped predictor, built
    (the engine runs the shift compiled when it compiles that predictor too, and calls
    the wrapper itself otherwise).

    Attributes
    ----------
    base : Predictor
        The wrapped predictor.
    """

    kernel: ClassVar[str] = ""
    base: Predictor

    @property
    def neutral(self) -> bool:
        """Whether the shift returns the wrapped predictor's forecast itself."""
        return False


@dataclass(frozen=True)
class DelayedForm(ShiftForm):
    """:class:`DelayedPredictor` as the compiled engine runs it.

    Attributes
    ----------
    delay_s : float
        The delay in seconds (>= 0).
    """

    kernel: ClassVar[str] = "delayed"
    delay_s: float = 0.0

    @property
    def neutral(self) -> bool:
        return self.delay_s == 0.0

    def samples(self, dt: float) -> int:
        """The delay in whole samples of spacing ``dt``, as the predictor rounds it.

        Parameters
        ----------
        dt : float
            The spacing of the samples (s).
        """
        return round(self.delay_s / float(dt))


@dataclass(frozen=True)
class NoisyForm(ShiftForm):
    """:class:`NoisyPredictor` as the compiled engine runs it.

    Attributes
    ----------
    sigma_m : float
        Standard deviation of the position error per axis (m, >= 0).
    seed : int
        Seed of the draws.
    """

    kernel: ClassVar[str] = "noisy"
    sigma_m: float = 0.0
    seed: int = 0

    @property
    def neutral(self) -> bool:
        return self.sigma_m == 0.0


@dataclass(frozen=True)
class ScaledForm(ShiftForm):
    """:class:`ScaledPredictor` as the compiled engine runs it.

    Attributes
    ----------
    scale : float
        Factor on the predicted displacement (>= 0).
    """

    kernel: ClassVar[str] = "scaled"
    scale: float = 1.0

    @property
    def neutral(self) -> bool:
        return self.scale == 1.0


@dataclass(frozen=True)
class DropoutForm(ShiftForm):
    """:class:`DropoutPredictor` as the compiled engine runs it.

    Attributes
    ----------
    p : float
        Probability that an agent's detections are missing during a block.
    duration_s : float
        Length of a block (s, > 0).
    seed : int
        Seed of the draws.
    """

    kernel: ClassVar[str] = "dropout"
    p: float = 0.0
    duration_s: float = 1.0
    seed: int = 0

    @property
    def neutral(self) -> bool:
        return self.p == 0.0


def noise_offsets(
    sigma: np.ndarray, seeds: np.ndarray, scenes: np.ndarray, frames: np.ndarray, ids: np.ndarray
) -> np.ndarray:
    """The position errors :class:`NoisyPredictor` adds, for many agents at once: row i
    is agent ``ids[i]``'s at frame ``frames[i]`` of the scene keyed ``scenes[i]``, with
    seed ``seeds[i]`` and standard deviation ``sigma[i]`` -- the same numbers as the
    predictor's own call on that agent (the hash folds the same keys in the same order).

    Parameters
    ----------
    sigma : ndarray of shape (N,)
        Standard deviations (m).
    seeds, scenes, frames, ids : ndarray of shape (N,)
        The keys of the draws (integers).
    """
    key = (seeds[:, None], scenes[:, None], frames[:, None], ids[:, None], np.arange(2))
    out: np.ndarray = sigma[:, None] * hash_normal(*key)
    return out


# batchable: the wrappers cost microseconds (a slow wrapped predictor stays slow)
class ShiftedPredictor(Predictor, batchable=True):
    """Base of the predictor shifts: a wrapped predictor, built by :meth:`reset`.

    Attributes
    ----------
    predictor : str or Predictor
        The wrapped predictor: a registered name (built with ``predictor_params``) or an
        instance (used as given, not copied).
    predictor_params : dict, optional
        Parameters of a predictor given by name.
    """

    predictor: Any
    predictor_params: dict[str, Any] | None
    base_: Predictor

    def reset(self) -> None:
        self.base_ = resolve_predictor(self.predictor, self.predictor_params, type(self).__name__)
        self.base_.reset()
        self._check()

    def _check(self) -> None:
        """Validate the shift's own parameters (one-line ValueErrors)."""

    def _base(self) -> Predictor:
        base = getattr(self, "base_", None)
        if base is None:
            self.reset()
            base = self.base_
        return base

    @staticmethod
    def _nonfinite_current(query: PredictionQuery, fc: Forecast) -> Forecast:
        """NaN rows (counted) for agents whose current position is not finite."""
        bad = ~_finite_rows(np.asarray(query.history[:, -1:], dtype=float))[:, 0]
        if bad.any():
            fc.positions = np.array(fc.positions, dtype=float, copy=True)
            fc.positions[bad] = np.nan
            fc.info["n_nonfinite_current"] = fc.info.get("n_nonfinite_current", 0) + int(bad.sum())
        return fc


# compiled: the engine runs this class (its DelayedForm) compiled (not inherited)
class DelayedPredictor(ShiftedPredictor, compiled="delayed"):
    """A predictor fed data ``delay_s`` old, its forecast used as current (not compensated).

    At a sampling time t the wrapped predictor sees the histories up to t - delay_s (the
    delay rounded to a whole number of samples) and its forecast of the positions at
    t - delay_s + dt, ..., + horizon dt is returned as the forecast for t + dt, ...: what a
    controller does with a perception pipeline whose latency it does not compensate. An
    agent not observed at t - delay_s is predicted from its last earlier observation
    (``n_stale``) or, if it had none, stands at its first observation (``n_unseen``). The
    history must be longer than the delay (``ValueError`` otherwise). A wrapped predictor
    that reads the true future (the oracle) gets the true future of t - delay_s.

    Parameters
    ----------
    predictor : str or Predictor
        The wrapped predictor (registered name or instance).
    delay_s : float
        Delay in seconds (>= 0; 0 returns the wrapped predictor's forecast itself).
    predictor_params : dict, optional
        Parameters of a predictor given by name.
    """

    def __init__(
        self,
        predictor: Any = "constant_velocity",
        delay_s: float = 0.5,
        predictor_params: dict[str, Any] | None = None,
    ) -> None:
        self.predictor = predictor
        self.delay_s = delay_s
        self.predictor_params = predictor_params

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{"delay_s": 0.8}, {"delay_s": 0.0}, {"predictor": "var", "delay_s": 0.4}]

    def compiled_state(self) -> DelayedForm:
        """This shift as the compiled engine runs it (after :meth:`reset`)."""
        return DelayedForm(self._base(), _number(self.delay_s, "delay_s"))

    def _check(self) -> None:
        _number(self.delay_s, "delay_s")

    def predict(self, query: PredictionQuery) -> Forecast:
        base = self._base()
        delay = _number(self.delay_s, "delay_s")
        k = round(delay / float(query.dt))
        if k == 0:
            return base.predict(query)
        hist = np.asarray(query.history, dtype=float)
        n, T, _ = hist.shape
        if k >= T:
            raise ValueError(
                f"delay_s={delay:g} s is {k} samples, but the history holds {T} samples "
                f"({T * query.dt:.3g} s): give a longer history (run parameter history) or a "
                "shorter delay"
            )
        old = hist[:, : T - k]
        cut = ~_finite_rows(old[:, -1:])[:, 0] if n else np.zeros(0, dtype=bool)
        n_stale = n_unseen = 0
        if cut.any():
            rows = np.flatnonzero(cut)
            fin = _finite_rows(old[rows])
            last = np.where(fin.any(axis=1), T - k - 1 - np.argmax(fin[:, ::-1], axis=1), -1)
            # an agent never seen before the cut: its first observation after it
            widened, n_stale, n_unseen = _restart_rows(hist[:, : T - k], rows, last)
            unseen = rows[last < 0]
            for i in unseen.tolist():
                seen = np.flatnonzero(_finite_rows(hist[i][None])[0])
                widened[i, -1] = hist[i, seen[0]] if seen.size else hist[i, -1]
            old = widened
        truth: Callable[[int], np.ndarray] | None = None
        if query.ground_truth is not None or query.truth_provider is not None:

            def truth(horizon: int) -> np.ndarray:  # the true future of t - delay
                known = hist[:, T - k :][:, :horizon]  # t - delay + 1 .. t: observed
                rest = horizon - known.shape[1]
                if rest <= 0:
                    return known
                out: np.ndarray = np.concatenate([known, query.future(rest)], axis=1)
                return out

        delayed = PredictionQuery(
            ids=query.ids,
            history=np.ascontiguousarray(old),
            dt=query.dt,
            horizon=query.horizon,
            t=query.t - k * query.dt,
            frame=query.frame - k,
            scene=query.scene,
            truth_provider=truth,
        )
        fc = base.predict(delayed)
        info = dict(fc.info)
        info["n_stale"] = info.get("n_stale", 0) + n_stale
        info["n_unseen"] = info.get("n_unseen", 0) + n_unseen
        out = Forecast(np.array(fc.positions, dtype=float), fc.covariance, info)
        return self._nonfinite_current(query, out)


# compiled: the engine runs this class (its NoisyForm) compiled (not inherited)
class NoisyPredictor(ShiftedPredictor, run_values={"random_state": "seed"}, compiled="noisy"):
    """A predictor whose forecasts carry a Gaussian position error of ``sigma_m`` per axis.

    One draw per agent and sampling time displaces the agent's whole forecast (every
    horizon step by the same offset): a forecast as good at predicting motion as the
    wrapped one, but off by a random position error. Draws are a hash of
    (``random_state``, scene, frame, agent id), so they do not depend on the other agents
    in the query or on the order of the calls.

    Parameters
    ----------
    predictor : str or Predictor
        The wrapped predictor (registered name or instance).
    sigma_m : float
        Standard deviation of the position error per axis, in metres (>= 0; 0 returns the
        wrapped predictor's forecast itself).
    random_state : int, optional
        Seed of the draws (None means 0).
    predictor_params : dict, optional
        Parameters of a predictor given by name.
    """

    def __init__(
        self,
        predictor: Any = "constant_velocity",
        sigma_m: float = 0.1,
        random_state: int | None = None,
        predictor_params: dict[str, Any] | None = None,
    ) -> None:
        self.predictor = predictor
        self.sigma_m = sigma_m
        self.random_state = random_state
        self.predictor_params = predictor_params

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{"sigma_m": 0.25, "random_state": 0}, {"sigma_m": 0.0}]

    def compiled_state(self) -> NoisyForm:
        """This shift as the compiled engine runs it (after :meth:`reset`)."""
        sigma = _number(self.sigma_m, "sigma_m")
        return NoisyForm(self._base(), sigma, int(self.random_state or 0))

    def _check(self) -> None:
        _number(self.sigma_m, "sigma_m")

    def predict(self, query: PredictionQuery) -> Forecast:
        base = self._base()
        sigma = _number(self.sigma_m, "sigma_m")
        fc = base.predict(query)
        if sigma == 0.0 or query.n_agents == 0:
            return fc
        seed = int(self.random_state or 0)
        ids = np.asarray(query.ids).astype(np.int64)
        key = (seed, scene_key(query.scene), int(query.frame), ids[:, None], np.arange(2))
        offset = sigma * hash_normal(*key)  # (N, 2)
        pos = np.asarray(fc.positions, dtype=float) + offset[:, None, :]
        return Forecast(pos, fc.covariance, dict(fc.info))


# compiled: the engine runs this class (its ScaledForm) compiled (not inherited)
class ScaledPredictor(ShiftedPredictor, compiled="scaled"):
    """A predictor whose predicted displacements are scaled by ``scale`` (0 = frozen).

    The forecast is ``current + scale * (forecast - current)``: ``scale = 0`` predicts
    every agent to stand still where it is (a frozen predictor), ``0.5`` half as far,
    ``2`` twice as far (a velocity error proportional to the speed).

    Parameters
    ----------
    predictor : str or Predictor
        The wrapped predictor (registered name or instance).
    scale : float
        Factor on the predicted displacement (>= 0; 1 returns the wrapped predictor's
        forecast itself).
    predictor_params : dict, optional
        Parameters of a predictor given by name.
    """

    def __init__(
        self,
        predictor: Any = "constant_velocity",
        scale: float = 0.0,
        predictor_params: dict[str, Any] | None = None,
    ) -> None:
        self.predictor = predictor
        self.scale = scale
        self.predictor_params = predictor_params

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{}, {"scale": 2.0}]

    def compiled_state(self) -> ScaledForm:
        """This shift as the compiled engine runs it (after :meth:`reset`)."""
        return ScaledForm(self._base(), _number(self.scale, "scale"))

    def _check(self) -> None:
        _number(self.scale, "scale")

    def predict(self, query: PredictionQuery) -> Forecast:
        base = self._base()
        scale = _number(self.scale, "scale")
        if scale == 1.0:
            return base.predict(query)
        if scale == 0.0:  # frozen: nothing is asked of the wrapped predictor
            cur = np.asarray(query.history[:, -1], dtype=float)
            pos = np.repeat(cur[:, None, :], query.horizon, axis=1)
            return self._nonfinite_current(query, Forecast(pos, None, {}))
        fc = base.predict(query)
        cur = np.asarray(query.history[:, -1], dtype=float)[:, None, :]
        with np.errstate(invalid="ignore"):  # a non-finite current row: NaN, counted below
            pos = cur + scale * (np.asarray(fc.positions, dtype=float) - cur)
        return self._nonfinite_current(query, Forecast(pos, fc.covariance, dict(fc.info)))


# compiled: the engine runs this class (its DropoutForm) compiled (not inherited)
class DropoutPredictor(ShiftedPredictor, run_values={"random_state": "seed"}, compiled="dropout"):
    """A predictor whose agents' detections go missing (probability p, duration_s at a time).

    Time (the scene's frame number x the sample spacing) is cut into blocks of
    ``duration_s`` seconds; in each block each agent's detections are missing with
    probability ``p``, independently (a hash of ``random_state``, scene, agent id and
    block). Missing samples are removed from the history the wrapped predictor sees; an
    agent whose current detection is missing is predicted from its last detection as if
    that were current (``n_stale``; not compensated, as :class:`DelayedPredictor`) or,
    with no detection in its history, stands at its first observation (``n_unseen``).
    ``n_dropped`` counts agents whose current detection was missing.

    Parameters
    ----------
    predictor : str or Predictor
        The wrapped predictor (registered name or instance).
    p : float
        Probability that an agent's detections are missing during a block (in [0, 1]; 0
        returns the wrapped predictor's forecast itself).
    duration_s : float
        Length of a block in seconds (> 0).
    random_state : int, optional
        Seed of the draws (None means 0).
    predictor_params : dict, optional
        Parameters of a predictor given by name.
    """

    def __init__(
        self,
        predictor: Any = "constant_velocity",
        p: float = 0.2,
        duration_s: float = 1.0,
        random_state: int | None = None,
        predictor_params: dict[str, Any] | None = None,
    ) -> None:
        self.predictor = predictor
        self.p = p
        self.duration_s = duration_s
        self.random_state = random_state
        self.predictor_params = predictor_params

    @classmethod
    def _unit_test_params(cls) -> list[dict[str, Any]]:
        return [{"p": 0.5, "duration_s": 0.8, "random_state": 1}, {"p": 0.0}]

    def compiled_state(self) -> DropoutForm:
        """This shift as the compiled engine runs it (after :meth:`reset`)."""
        self._check()
        p, duration = float(self.p), float(self.duration_s)
        return DropoutForm(self._base(), p, duration, int(self.random_state or 0))

    def _check(self) -> None:
        _number(self.p, "p", high=1.0)
        if _number(self.duration_s, "duration_s") <= 0:
            raise ValueError(f"duration_s must be > 0, got {self.duration_s!r}")

    def missing(self, query: PredictionQuery) -> np.ndarray:
        """(N, T) mask of the history samples whose detection is missing."""
        self._check()
        hist = query.history
        n, T = hist.shape[0], hist.shape[1]
        frames = int(query.frame) - (T - 1) + np.arange(T)
        block = np.floor(frames * float(query.dt) / float(self.duration_s) + 1e-9)
        ids = np.asarray(query.ids).astype(np.int64)
        u = hash_uniform(
            int(self.random_state or 0),
            scene_key(query.scene),
            ids[:, None],
            block.astype(np.int64)[None, :],
            2,
        )
        out: np.ndarray = (u < float(self.p)).reshape(n, T)
        return out

    def predict(self, query: PredictionQuery) -> Forecast:
        base = self._base()
        p = _number(self.p, "p", high=1.0)
        self._check()
        if p == 0.0 or query.n_agents == 0:
            return base.predict(query)
        hist = np.asarray(query.history, dtype=float)
        miss = self.missing(query)
        seen = hist.copy()
        seen[miss] = np.nan
        gone = miss[:, -1] & _finite_rows(hist[:, -1:])[:, 0]
        n_stale = n_unseen = 0
        if gone.any():
            rows = np.flatnonzero(gone)
            fin = _finite_rows(seen[rows])
            T = hist.shape[1]
            last = np.where(fin.any(axis=1), T - 1 - np.argmax(fin[:, ::-1], axis=1), -1)
            seen, n_stale, n_unseen = _restart_rows(seen, rows, last)
            for i in rows[last < 0].tolist():  # never detected in the history: first sample
                first = np.flatnonzero(_finite_rows(hist[i][None])[0])
                seen[i, -1] = hist[i, first[0]]
        shown = PredictionQuery(
            ids=query.ids,
            history=seen,
            dt=query.dt,
            horizon=query.horizon,
            t=query.t,
            frame=query.frame,
            scene=query.scene,
            ground_truth=query.ground_truth,
            truth_provider=query.truth_provider,
        )
        fc = base.predict(shown)
        info = dict(fc.info)
        info["n_dropped"] = info.get("n_dropped", 0) + int(gone.sum())
        info["n_stale"] = info.get("n_stale", 0) + n_stale
        info["n_unseen"] = info.get("n_unseen", 0) + n_unseen
        out = Forecast(np.array(fc.positions, dtype=float), fc.covariance, info)
        return self._nonfinite_current(query, out)
