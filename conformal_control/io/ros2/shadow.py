"""Shadow mode: what the conformal controller would have commanded on a recorded bag.

:func:`shadow` reads a robot's ROS 2 bag (:func:`~conformal_control.io.ros2.bag.read_bag`),
feeds its people to a step-wise controller -- :class:`~conformal_control.families.cbf.StepwiseCBF`
(``family="cbf"``) or :class:`~conformal_control.families.mpc.StepwiseMPC` (any registered
planning family: ``mpc``, ``acp_mpc``, ``ecp_mpc``, ``fcp_mpc``, ``soft_mpc``, a
plugin's) -- as a live node would, and asks it for a command at every control instant,
with the robot's **recorded** state: the robot moves as it did, the commands are what the
controller *would* have sent. Nothing is simulated.

Timing. The controller needs samples on a grid ``t = k dt``: the grid starts at the first
people message that has odometry before it (``t = 0``), ``dt`` is ``tau / n`` with ``n``
the whole number nearest to ``tau`` over the people topic's mean period (or the ``dt``
given), and each people message is placed in the grid slot nearest its stamp (its
positions unchanged: stamp jitter under ``dt / 2`` is ignored). Counted in the result,
never silent:

* ``n_merged``: messages that fell in a slot another message was nearer to (dropped);
* ``n_missing``: empty slots between sampling times (a sensor dropout: the controller
  scores the interval on the samples it has);
* ``n_held``: empty slots at a sampling time, where the controller must sense: the
  previous sample is observed again (the held people are up to that many ``dt`` old).

The robot's state at a control instant ``k dt + j dt / substeps`` is its odometry
interpolated linearly at that time (position, velocity in the odometry's frame, heading
for the body-frame command). The run covers the time where both topics have data; the
interval still open when it ends is not scored (its truth is not in the recording).

Outputs (:meth:`ShadowResult.save`): ``commands.csv`` (one row per control instant),
``config.json`` (every setting, the bag, the counts), ``shadow_bag/`` (a ROS 2 bag:
``/cmd_vel_safe`` ``geometry_msgs/msg/Twist`` in the robot's body frame,
``/conformal/lambda`` and ``/conformal/loss`` ``std_msgs/msg/Float64``, stamped on the
recorded bag's clock so both play together), ``plot.png`` and ``guarantee.png``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ... import __version__
from ...core.exceptions import DataFormatError, InputError
from ...core.loop import LoopResult
from .bag import RecordedBag, read_bag
from .types import FLOAT64, TWIST

__all__ = ["COLUMNS", "ShadowResult", "shadow"]

#: The columns of ``commands.csv``.
COLUMNS = (
    "t",
    "stamp_ns",
    "vx",
    "vy",
    "vx_body",
    "vy_body",
    "lambda",
    "loss",
    "fallback",
)
#: Topics of the output bag.
CMD_TOPIC, LAMBDA_TOPIC, LOSS_TOPIC = "/cmd_vel_safe", "/conformal/lambda", "/conformal/loss"
#: Keywords of the controller's ``Stream`` (the rest go to the controller).
_STREAM_KEYS = ("tau", "dt", "substeps", "sensing_radius", "history")


@dataclass
class ShadowResult:
    """What :func:`shadow` computed.

    Attributes
    ----------
    bag : RecordedBag
        The recording read.
    commands : dict of str to ndarray
        The columns of ``commands.csv`` (:data:`COLUMNS`): ``t`` (s since the start),
        ``stamp_ns`` (the bag's clock), ``vx``, ``vy`` (m/s, the odometry's frame),
        ``vx_body``, ``vy_body`` (m/s, the robot's body frame: what ``/cmd_vel_safe``
        carries), ``lambda`` (in force at that instant), ``loss`` (of the interval closed
        there, NaN elsewhere), ``fallback`` (1 if the controller fell back).
    result : LoopResult
        The intervals, lambda and the guarantee monitor.
    config : dict
        Every setting (written as ``config.json``).
    counts : dict of str to int
        ``n_samples``, ``n_merged``, ``n_missing``, ``n_held``, ``n_steps``,
        ``n_fallback``.
    """

    bag: RecordedBag
    commands: dict[str, np.ndarray]
    result: LoopResult
    config: dict[str, Any]
    counts: dict[str, int] = field(default_factory=dict)

    def summary(self) -> str:
        """A few lines: the span, the counts, the average loss and lambda."""
        c, res = self.counts, self.result
        t = self.commands["t"]
        span = float(t[-1]) if t.size else 0.0
        sp = np.hypot(self.commands["vx"], self.commands["vy"])
        return "\n".join(
            [
                f"{'commands':<22}{c['n_steps']} over {span:.2f} s "
                f"(dt {self.config['stream']['dt']:g} s, {self.config['stream']['substeps']} "
                "per sample)",
                f"{'people samples':<22}{c['n_samples']} ({c['n_merged']} merged, "
                f"{c['n_missing']} missing, {c['n_held']} held)",
                f"{'people':<22}{len(self.bag.people.names)}",
                f"{'intervals scored':<22}{res.n_updates}",
                f"{'l_avg':<22}{res.l_avg:.4g} (epsilon {self.config['epsilon']:g})",
                f"{'lambda_final':<22}{res.lambda_final:.4g}",
                f"{'fallbacks':<22}{c['n_fallback']}",
                f"{'mean command speed':<22}{float(sp.mean()) if sp.size else math.nan:.3f} m/s",
            ]
        )

    def save(self, out: str | Path, *, plots: bool = True) -> Path:
        """Write ``commands.csv``, ``config.json``, ``shadow_bag/`` and the plots into
        the folder ``out`` (created; an existing ``shadow_bag`` in it is an error).

        Parameters
        ----------
        out : path
            The output folder.
        plots : bool
            Draw ``plot.png`` and ``guarantee.png``.

        Returns
        -------
        Path
            ``out``.
        """
        folder = Path(out)
        bag_dir = folder / "shadow_bag"
        if bag_dir.exists() or bag_dir.is_symlink():
            raise InputError(f"{bag_dir} exists already: give a new --out folder")
        folder.mkdir(parents=True, exist_ok=True)
        with (folder / "commands.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(COLUMNS)
            cols = [self.commands[c] for c in COLUMNS]
            for row in zip(*cols, strict=True):
                w.writerow(_cells(row))
        (folder / "config.json").write_text(json.dumps(self.config, indent=2) + "\n")
        self.recording().write_bag(bag_dir, storage="mcap")
        if plots:
            from .plots import plot_shadow

            plot_shadow(self, folder / "plot.png")
            from ..plotting.guarantee import plot_guarantee

            plot_guarantee(
                self.result.monitor, folder / "guarantee.png", title=f"shadow: {self.bag.path.name}"
            )
        return folder

    def recording(self) -> Any:
        """The output bag's messages (a :class:`~conformal_control.io.ros2.writer.Recording`)."""
        from .writer import Recording, float64, twist

        rec = Recording()
        c = self.commands
        for i in range(c["t"].size):
            ns = int(c["stamp_ns"][i])
            rec.add(CMD_TOPIC, TWIST, ns, twist(c["vx_body"][i], c["vy_body"][i]))
            rec.add(LAMBDA_TOPIC, FLOAT64, ns, float64(c["lambda"][i]))
            if math.isfinite(c["loss"][i]):
                rec.add(LOSS_TOPIC, FLOAT64, ns, float64(c["loss"][i]))
        return rec


def _cells(row: Sequence[Any]) -> list[str]:
    out = []
    for name, v in zip(COLUMNS, row, strict=True):
        if name in ("stamp_ns", "fallback"):
            out.append(str(int(v)))
        else:
            out.append(repr(float(v)) if math.isfinite(v) else "")
    return out


# ---------------------------------------------------------------------------- timing
def _grid_dt(stamps: np.ndarray, tau: float) -> float:
    """``tau / n``, ``n`` the whole number nearest ``tau`` over the mean period (the span
    over the number of gaps: stamp jitter averages out, a few dropouts barely move it)."""
    if stamps.size < 2:
        raise DataFormatError("the people topic has one message: no rate to run at")
    period = float(stamps[-1] - stamps[0]) / (stamps.size - 1) / 1e9
    return tau / max(1, round(tau / period))


def _slots(stamps: np.ndarray, t0: int, dt: float, n_slots: int) -> tuple[np.ndarray, int]:
    """Per grid slot, the index of the people message placed there (-1: none), and the
    number of messages dropped for a nearer one."""
    chosen = np.full(n_slots, -1, dtype=np.int64)
    best = np.full(n_slots, np.inf)
    merged = 0
    rel = (stamps - t0) / 1e9
    for i, t in enumerate(rel.tolist()):
        k = round(t / dt)
        if k < 0 or k >= n_slots:
            continue
        off = abs(t - k * dt)
        if chosen[k] >= 0:
            merged += 1
            if off >= best[k]:
                continue
        chosen[k], best[k] = i, off
    return chosen, merged


def _interp(t_ns: np.ndarray, stamps: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values`` at times ``t_ns``."""
    x = (stamps - stamps[0]) / 1e9
    q = (t_ns - stamps[0]) / 1e9
    cols = values.reshape(values.shape[0], -1)
    out = np.stack([np.interp(q, x, cols[:, j]) for j in range(cols.shape[1])], axis=1)
    return out.reshape((t_ns.size, *values.shape[1:]))


# ---------------------------------------------------------------------------- controller
def _controller(family: str, predictor: Any, params: dict[str, Any], tau: float, dt: float) -> Any:
    from ...families.cbf.stepwise import StepwiseCBF, Stream

    stream_kw = {k: params.pop(k) for k in _STREAM_KEYS if k in params}
    stream_kw.pop("tau", None)
    stream_kw.pop("dt", None)
    stream_kw.setdefault("substeps", 1)
    stream = Stream(tau=tau, dt=dt, **stream_kw)
    if family == "cbf":
        return StepwiseCBF(predictor, stream=stream, **params)
    from ...families.mpc.stepwise import StepwiseMPC

    return StepwiseMPC(predictor, family=family, stream=stream, **params)


def _goal(goal: Sequence[float]) -> np.ndarray:
    try:
        g = np.asarray(goal, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"goal must be two numbers X,Y (m), got {goal!r}") from None
    if g.shape != (2,) or not np.isfinite(g).all():
        raise InputError(f"goal must be two finite numbers X,Y (m), got {goal!r}")
    return g


def shadow(
    bag: str | Path | RecordedBag,
    goal: Sequence[float],
    *,
    people_topic: str = "/people",
    odom_topic: str = "/odom",
    family: str = "cbf",
    predictor: Any = "constant_velocity",
    params: dict[str, Any] | None = None,
    out: str | Path | None = None,
) -> ShadowResult:
    """Run a conformal controller in shadow mode over a ROS 2 bag (module docstring).

    Parameters
    ----------
    bag : path or RecordedBag
        A bag folder, ``.mcap`` or ``.db3`` file, or a bag already read.
    goal : (x, y)
        The robot's goal (m) in the odometry's frame.
    people_topic : str
        ``people_msgs/msg/People`` or ``visualization_msgs/msg/MarkerArray`` topic.
    odom_topic : str
        ``nav_msgs/msg/Odometry`` topic.
    family : str
        ``cbf`` (:class:`~conformal_control.families.cbf.StepwiseCBF`) or a planning family
        (any registered one -- ``mpc``, ``acp_mpc``, ``ecp_mpc``, ``fcp_mpc``,
        ``soft_mpc``, a plugin's: :class:`~conformal_control.families.mpc.StepwiseMPC` with its
        velocity plant).
    predictor : str or Predictor
        A registered predictor name or an instance.
    params : dict, optional
        The controller's keywords (``epsilon``, ``eta``, ``d_c``, ``v_max``, ...) and the
        stream's (``tau``, default 0.4 s; ``dt``, default from the data; ``substeps``,
        default 1; ``sensing_radius``; ``history``), SI units.
    out : path, optional
        Save the outputs there (:meth:`ShadowResult.save`).

    Returns
    -------
    ShadowResult
        The commands, the intervals and the counts.
    """
    rec = (
        bag
        if isinstance(bag, RecordedBag)
        else read_bag(bag, people_topic=people_topic, odom_topic=odom_topic)
    )
    g = _goal(goal)
    kw = dict(params or {})
    given = dict(kw)
    tau = float(kw.pop("tau", 0.4))
    if not math.isfinite(tau) or tau <= 0:
        raise InputError(f"tau must be a finite number > 0 (s), got {tau!r}")
    people, odom = rec.people, rec.odometry
    dt_given = kw.pop("dt", None)
    dt = float(dt_given) if dt_given is not None else _grid_dt(people.stamps, tau)
    ctrl = _controller(family, predictor, kw, tau, dt)
    if ctrl.state_dim != 4:
        raise InputError(
            f"shadow mode drives velocity plants (state x, y, vx, vy); this family's plant "
            f"has {ctrl.state_dim} numbers"
        )
    start = np.flatnonzero(people.stamps >= odom.stamps[0])
    if start.size == 0:
        raise DataFormatError(
            f"{rec.path}: every people message ({people.topic}) comes before the first "
            f"odometry ({odom.topic}): no overlap in time"
        )
    t0 = int(people.stamps[start[0]])
    end = min(int(people.stamps[-1]), int(odom.stamps[-1]))
    n_slots = math.floor((end - t0) / 1e9 / dt + 1e-9) + 1
    if n_slots < 2:
        raise DataFormatError(
            f"{rec.path}: people and odometry overlap for {(end - t0) / 1e9:.3f} s, less "
            f"than one sample period ({dt:g} s)"
        )
    chosen, merged = _slots(people.stamps, t0, dt, n_slots)
    n = ctrl.tau_samples
    sub = ctrl.substeps
    # the last control instant must lie within the odometry: drop the final samples
    # whose control instants would need odometry after its end
    n_slots = min(n_slots, math.floor((odom.stamps[-1] - t0) / 1e9 / dt + 1e-9))
    n_slots = max(n_slots, 1)
    times = np.arange(n_slots * sub) * (dt / sub)
    t_ns = t0 + np.round(times * 1e9).astype(np.int64)
    xy = _interp(t_ns, odom.stamps, odom.xy)
    vel = _interp(t_ns, odom.stamps, odom.velocity)
    yaw = _interp(t_ns, odom.stamps, odom.yaw)
    cmd = np.zeros((t_ns.size, 2))
    lam = np.zeros(t_ns.size)
    loss = np.full(t_ns.size, np.nan)
    fallback = np.zeros(t_ns.size, dtype=np.int64)
    held = missing = 0
    last: int | None = None
    n_fb = 0
    for k in range(n_slots):
        i = int(chosen[k])
        if i < 0 and k % n == 0:
            i = -1 if last is None else last
            held += 1
        if i >= 0:
            ctrl.observe(people.ids[i], people.positions[i], t=k * dt)
            last = i
        else:
            missing += 1
        for j in range(sub):
            s = k * sub + j
            before = len(ctrl.stepper.intervals_)
            ego = np.r_[xy[s], vel[s]]
            cmd[s] = ctrl.step(ego, t=k * dt + j * (dt / sub), goal=g)
            lam[s] = ctrl.lam
            if len(ctrl.stepper.intervals_) > before:
                closed = ctrl.stepper.intervals_[-1].loss
                if closed is not None:
                    loss[s] = closed
            now = int(ctrl.stats().get("n_fallback", 0))
            fallback[s] = int(now > n_fb)
            n_fb = now
    result = ctrl.result()  # the interval still open when the data ends is not scored
    c, s_ = np.cos(yaw), np.sin(yaw)
    body = np.stack([c * cmd[:, 0] + s_ * cmd[:, 1], -s_ * cmd[:, 0] + c * cmd[:, 1]], axis=1)
    commands = {
        "t": np.round(times, 9),
        "stamp_ns": t_ns,
        "vx": cmd[:, 0],
        "vy": cmd[:, 1],
        "vx_body": body[:, 0],
        "vy_body": body[:, 1],
        "lambda": lam,
        "loss": loss,
        "fallback": fallback,
    }
    counts = {
        "n_samples": int((chosen[:n_slots] >= 0).sum()),
        "n_merged": merged,
        "n_missing": missing,
        "n_held": held,
        "n_steps": int(t_ns.size),
        "n_fallback": int(fallback.sum()),
    }
    epsilon = float(getattr(ctrl.stepper.rule, "epsilon", math.nan))
    config = {
        "conformal_control": __version__,
        "bag": str(rec.path),
        "people_topic": people.topic,
        "people_type": people.msgtype,
        "odom_topic": odom.topic,
        "frame": odom.frame,
        "people_frame": people.frame,
        "people_transform": list(rec.transform),
        "body_frame": odom.child_frame,
        "goal": g.tolist(),
        "family": family,
        "predictor": predictor if isinstance(predictor, str) else type(predictor).__name__,
        "params": {k: v for k, v in given.items() if k not in ("tau", "dt")},
        "epsilon": epsilon,
        "stream": {"tau": tau, "dt": dt, "substeps": sub, "dt_from_data": dt_given is None},
        "t0_ns": t0,
        "counts": counts,
        "people": dict(enumerate(people.names)),
        "outputs": {
            "commands.csv": list(COLUMNS),
            "shadow_bag": {CMD_TOPIC: TWIST, LAMBDA_TOPIC: FLOAT64, LOSS_TOPIC: FLOAT64},
        },
    }
    res = ShadowResult(bag=rec, commands=commands, result=result, config=config, counts=counts)
    if out is not None:
        res.save(out)
    return res
