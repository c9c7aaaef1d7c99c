"""Predictor shifts of the benchmark: one named, documented table.

A shift replaces the predictor every method uses by a degraded one
(:mod:`conformal_control.predictors.shift`), or by a learned one; ``bench run --shift
NAME[,NAME]`` runs every method under each, and every row carries its shift. The table:

=================  ==========================================================================
``nominal``        the benchmark's predictor as it is (constant velocity)
``delay-0.2s``     forecasts made from data 0.2 s old, not compensated (``delayed``)
``delay-0.5s``     the same, 0.5 s
``delay-1s``       the same, 1 s
``noise-0.1m``     every forecast displaced by a Gaussian position error of 0.1 m per axis
                   (``noisy``; one draw per agent and sampling time, seeded by the run's seed)
``noise-0.25m``    the same, 0.25 m
``frozen``         every pedestrian predicted to stand still (``scaled``, scale 0)
``dropout-0.3-1s`` each pedestrian's detections missing 30 % of the time in blocks of 1 s,
                   predicted from its last detection meanwhile (``dropout``)
``learned``        Trajectron++ (Salzmann et al. 2020), the published predictions of its
                   pretrained models on the ETH/UCY test scenes (``recorded``, from the data
                   folder's ``external/trajectron-ethucy``): only the scenarios of biwi_eth,
                   biwi_hotel and crowds_zara01, the recordings it covers
=================  ==========================================================================

A shift wraps the predictor a method would use (the benchmark's, or the method's own, e.g.
the oracle's); ``learned`` replaces it (agents without a recorded forecast fall back to
constant velocity, counted).
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

__all__ = ["SHIFTS", "Shift", "get_shift", "parse_shifts"]

#: Trajectron++ predictions per scene name (the ETH/UCY scenes' names): file, and the
#: step length where the scene's clock is not the files' 0.4 s (biwi_eth on its original
#: clock: 0.667 s per row, see :mod:`conformal_control.data.ethucy`).
_TRAJECTRON = "external/trajectron-ethucy"
_LEARNED_FILES: dict[str, Any] = {
    "biwi_eth": {"file": f"{_TRAJECTRON}/eth.csv.gz"},
    "biwi_eth:corrected": {"file": f"{_TRAJECTRON}/eth.csv.gz", "step_s": 2.0 / 3.0},
    "biwi_hotel": {"file": f"{_TRAJECTRON}/hotel.csv.gz"},
    "crowds_zara01": {"file": f"{_TRAJECTRON}/zara1.csv.gz"},
}


@dataclass(frozen=True)
class Shift:
    """One predictor shift (see the module docstring).

    Attributes
    ----------
    name : str
    description : str
    predictor : str or None
        The registered predictor that wraps (or replaces) the method's; None: unchanged.
    params : mapping
        Its parameters.
    wraps : bool
        Whether the method's predictor is passed as the wrapper's ``predictor``.
    recordings : tuple of str or None
        Only the scenarios of these recordings (None: every scenario).
    data_root : bool
        Whether the benchmark's data folder is passed as ``data_root`` (files it reads).
    """

    name: str
    description: str
    predictor: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    wraps: bool = True
    recordings: tuple[str, ...] | None = None
    data_root: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def covers(self, recording: str) -> bool:
        """Whether the shift runs on a scenario of this recording."""
        return self.recordings is None or recording in self.recordings

    def predictor_for(
        self,
        predictor: str,
        predictor_params: Mapping[str, Any] | None = None,
        data_root: str | None = None,
    ) -> tuple[str, dict[str, Any] | None]:
        """The (name, params) of the predictor a method using ``predictor`` runs with."""
        if self.predictor is None:
            return predictor, (dict(predictor_params) if predictor_params else None)
        params: dict[str, Any] = dict(self.params)
        if self.wraps:
            params["predictor"] = predictor
            if predictor_params:
                params["predictor_params"] = dict(predictor_params)
        if self.data_root and data_root is not None:
            params["data_root"] = str(data_root)
        return self.predictor, params

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "predictor": self.predictor,
            "params": dict(self.params),
            "wraps": self.wraps,
            "recordings": None if self.recordings is None else list(self.recordings),
        }


_TABLE: tuple[Shift, ...] = (
    Shift("nominal", "the benchmark's predictor as it is (constant velocity)"),
    Shift(
        "delay-0.2s", "forecasts from data 0.2 s old, not compensated", "delayed", {"delay_s": 0.2}
    ),
    Shift(
        "delay-0.5s", "forecasts from data 0.5 s old, not compensated", "delayed", {"delay_s": 0.5}
    ),
    Shift("delay-1s", "forecasts from data 1 s old, not compensated", "delayed", {"delay_s": 1.0}),
    Shift(
        "noise-0.1m",
        "forecasts displaced by a Gaussian position error of 0.1 m per axis",
        "noisy",
        {"sigma_m": 0.1},
    ),
    Shift(
        "noise-0.25m",
        "forecasts displaced by a Gaussian position error of 0.25 m per axis",
        "noisy",
        {"sigma_m": 0.25},
    ),
    Shift("frozen", "every pedestrian predicted to stand still", "scaled", {"scale": 0.0}),
    Shift(
        "dropout-0.3-1s",
        "detections missing 30 % of the time in blocks of 1 s (forecast from the last one)",
        "dropout",
        {"p": 0.3, "duration_s": 1.0},
    ),
    Shift(
        "learned",
        "Trajectron++ published predictions (biwi_eth, biwi_hotel, crowds_zara01 only)",
        "recorded",
        {"path": _LEARNED_FILES, "step_s": 0.4, "frames_per_step": 10.0},
        wraps=False,
        recordings=(
            "ethucy:biwi_eth",
            "ethucy:biwi_eth:corrected",
            "ethucy:biwi_hotel",
            "ethucy:crowds_zara01",
        ),
        data_root=True,
    ),
)

#: name -> shift, in the documented order.
SHIFTS: dict[str, Shift] = {s.name: s for s in _TABLE}


def get_shift(name: str) -> Shift:
    """The shift named ``name`` (a one-line error with the known names otherwise)."""
    try:
        return SHIFTS[name]
    except KeyError:
        close = difflib.get_close_matches(name, SHIFTS, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"unknown shift {name!r}{hint} known: {', '.join(SHIFTS)}") from None


def parse_shifts(text: str | None) -> list[Shift]:
    """``"nominal,delay-0.5s"`` -> the shifts (default: nominal); duplicates removed."""
    names = [n.strip() for n in (text or "nominal").split(",") if n.strip()]
    if not names:
        raise ValueError("--shift needs at least one shift name")
    out: list[Shift] = []
    for n in names:
        s = get_shift(n)
        if s not in out:
            out.append(s)
    return out
