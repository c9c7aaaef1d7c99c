"""The configurations of the paper's Tables I and II and the numbers it printed.

Every row is run in two variants, because ``a`` sets a floor under lambda. Lambda is
added to the constraint of every sensed agent, and a far agent (no gradient, h = h_max =
1/2) leaves the row ``a h_max + lambda >= 0``, which no velocity can meet once lambda <
-a h_max (:meth:`~conformal_control.families.cbf.constraint.ConformalConstraint.lambda_floor`).
With Table II's a = 1 and epsilon = -0.25 the target is then out of reach: the fallback
acts at almost every step and the robot never reaches its goal. So:

* ``printed`` - the parameters as the paper prints them (Table I: a = 0.1, Table II: a = 1);
* ``published`` - as the published code effectively ran them: it hard-coded
  alpha(h) = 10 h whatever ``a`` said, so a = 10 (per frame).

All other parameters are the printed ones, in the paper's units (px, frames); the loss
scale is 1 per frame. Algorithm 1 runs as published: the toolkit's edge rule (an agent
already within the collision distance gets an escape row, ``edge="escape"``, the default
elsewhere) is off: every run gets ``edge="paper"`` (:data:`PAPER_EDGE`). The published
code's other defects (velocity scaling, gradient power, loss window, lambda x tau in the
update, vanishing agents) are *not* reproduced.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...data.scenes import PUBLISHED_A, TABLE_I, TABLE_II

__all__ = ["PAPER_EDGE", "PAPER_TABLES", "VARIANTS", "PaperRow", "PaperTable", "variant_a"]

#: The run parameters every reproduced run gets besides the table's: Algorithm 1 as
#: published, without the toolkit's edge rule.
PAPER_EDGE: dict[str, str] = {"edge": "paper"}

#: variant name -> description
VARIANTS: dict[str, str] = {
    "printed": "parameters as printed in the paper",
    "published": f"as the published code ran them: alpha(h) = {PUBLISHED_A:g} h",
}


@dataclass(frozen=True)
class PaperRow:
    """One row of a table: its label, what differs from the table's base, paper values.

    ``oracle`` rows replace the predictor by the true future (the gt baseline).
    """

    label: str
    params: dict[str, Any]
    learn: bool
    paper: dict[str, float | None]
    oracle: bool = False


@dataclass(frozen=True)
class PaperTable:
    """A table: scene, shared parameters (paper units), the printed ``a``, its rows."""

    name: str
    title: str
    scene: str
    base: dict[str, Any]
    a_printed: float
    rows: tuple[PaperRow, ...] = field(default_factory=tuple)


def _p(t: float, n: int, d: float, lavg: float | None = None) -> dict[str, float | None]:
    return {"t_goal": t, "n_collide": n, "d_min": d, "l_avg": lavg}


_T1_BASE = {k: v for k, v in TABLE_I.items() if k not in ("a", "eta")}
_T2_BASE = {k: v for k, v in TABLE_II.items() if k not in ("a", "tau", "eta")}

TABLE_1 = PaperTable(
    "table1",
    "Table I: gates_1, eta = 100, tau = 12 frames, varying epsilon",
    "gates_1",
    {**_T1_BASE, "loss_scale": 1.0},
    TABLE_I["a"],
    (
        PaperRow("eps=-0.4", {"epsilon": -0.4, "eta": 100.0}, True, _p(19.2, 0, 4.098, -0.3949)),
        PaperRow("eps=-0.2", {"epsilon": -0.2, "eta": 100.0}, True, _p(19.2, 0, 4.098, -0.1865)),
        PaperRow("eps=0", {"epsilon": 0.0, "eta": 100.0}, True, _p(19.2, 4, 0.9031, 0.008016)),
        PaperRow("eps=0.2", {"epsilon": 0.2, "eta": 100.0}, True, _p(18.63, 0, 1.639, 0.2008)),
        PaperRow("eps=0.4", {"epsilon": 0.4, "eta": 100.0}, True, _p(14.63, 18, 0.4813, 0.4007)),
        PaperRow("pred/noLearn", {"epsilon": 0.0}, False, _p(13.9, 14, 0.8311)),
        PaperRow("gt/noLearn", {"epsilon": 0.0}, False, _p(13.9, 13, 0.7764), oracle=True),
    ),
)

TABLE_2 = PaperTable(
    "table2",
    "Table II: nexus_4, epsilon = -0.25, varying tau (frames) and eta",
    "nexus_4",
    {**_T2_BASE, "loss_scale": 1.0},
    TABLE_II["a"],
    (
        PaperRow("tau=4, eta=0.1", {"tau": 4, "eta": 0.1}, True, _p(9.067, 6, 0.4059, -0.2052)),
        PaperRow("tau=4, eta=1", {"tau": 4, "eta": 1.0}, True, _p(9.1, 2, 0.8881, -0.2415)),
        PaperRow("tau=4, noLearn", {"tau": 4}, False, _p(8.933, 13, 0.4493)),
        PaperRow("tau=8, eta=0.1", {"tau": 8, "eta": 0.1}, True, _p(9.067, 6, 1.046, -0.1949)),
        PaperRow("tau=8, eta=1", {"tau": 8, "eta": 1.0}, True, _p(9.133, 3, 0.4257, -0.2284)),
        PaperRow("tau=8, noLearn", {"tau": 8}, False, _p(8.933, 13, 0.3877)),
        PaperRow("gt, noLearn", {"tau": 4}, False, _p(8.967, 11, 0.5087), oracle=True),
    ),
)

PAPER_TABLES: dict[str, PaperTable] = {t.name: t for t in (TABLE_1, TABLE_2)}


def variant_a(table: PaperTable, variant: str) -> float:
    """The ``a`` of a variant: the printed one, or the published code's 10."""
    if variant == "printed":
        return table.a_printed
    if variant == "published":
        return PUBLISHED_A
    raise ValueError(f"unknown variant {variant!r}; use {', '.join(VARIANTS)}")
