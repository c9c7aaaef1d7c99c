"""Every name resolved in one place: recorded and built-in scenes
(:mod:`~conformal_control.data.scenes`), the scenarios of the shipped benchmark suites
(:mod:`~conformal_control.data.suites`, ``scenario:<suite>/<id>``), and the recordings and
data sets the other commands name (``fetch-data --only``, ``eval-predictor --dataset``,
``train-predictor --dataset``).

**One name per recording.** An ETH/UCY recording is ``ethucy:<recording>``
(``ethucy:crowds_zara01``, the file's own name); an SDD video ``sdd:<scene>/video<N>``.
The names the literature and the data folder use are aliases, resolved here and nowhere
else:

* ``ethucy:<split>`` (``eth``, ``hotel``, ``zara1``, ``zara2``: the leave-one-scene-out
  split, named for its test recording) is that recording where a recording is meant
  (:func:`scene_name`); ``ethucy:univ`` holds two recordings (``students001``,
  ``students003``), so a scene must name one. Where a *data set* is meant (the
  leave-one-out split a predictor is evaluated on and trained for, :func:`dataset_name`),
  a recording's name is its split: ``ethucy:crowds_zara01`` is the ``zara1`` split;
* ``sdd:<scene>_<N>`` (``fetch-data``'s form) is ``sdd:<scene>/video<N>``.

A name given without its prefix (``zara1``, ``crowds_zara01``, ``nexus/video3``,
``quad_2``) is an unknown scene whose error suggests the full name.

This module sits above the loaders (a suite's scenario is read through the scene loader),
so none of them needs the others' name resolution.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from typing import Any

from ..core.exceptions import InputError
from . import scenes
from .ethucy import ETHUCY_RECORDINGS, ETHUCY_SCENES
from .scene import Scene
from .suites import load_scenario, shipped_scenario

__all__ = [
    "dataset_name",
    "ethucy_split",
    "fetch_selector",
    "load_scene",
    "scene_name",
    "sdd_video_name",
    "suggest_scene",
]

#: ETH/UCY split -> its recordings (the inverse of ``ETHUCY_RECORDINGS``).
_SPLIT_RECORDINGS: dict[str, tuple[str, ...]] = {
    split: tuple(r for r, s in ETHUCY_RECORDINGS.items() if s == split) for split in ETHUCY_SCENES
}
_SDD_SHORT = re.compile(r"^(?P<scene>[A-Za-z]+)_(?P<video>\d+)$")
_SDD_LONG = re.compile(r"^(?P<scene>[A-Za-z]+)/video(?P<video>\d+)$")


def _ethucy_parts(name: str) -> tuple[str, str]:
    """``ethucy:<stem>[:corrected]`` -> (stem, suffix)."""
    stem, _, suffix = name[len("ethucy:") :].partition(":")
    return stem, (":" + suffix if suffix else "")


def _unknown_ethucy(stem: str, name: str) -> InputError:
    import difflib

    names = [*ETHUCY_RECORDINGS, *ETHUCY_SCENES]
    close = difflib.get_close_matches(stem, names, n=1, cutoff=0.6)
    hint = ""
    if close:
        hint = f" did you mean 'ethucy:{_recording_of(close[0]) or close[0]}'?"
    return InputError(
        f"unknown ETH/UCY recording {name!r};{hint} the recordings are "
        f"{', '.join('ethucy:' + r for r in ETHUCY_RECORDINGS)} (the splits eth, hotel, "
        "zara1, zara2 name their recording too)"
    )


def _recording_of(stem: str) -> str | None:
    """The recording a stem names (a recording, or a split holding one), else None."""
    if stem in ETHUCY_RECORDINGS:
        return stem
    held = _SPLIT_RECORDINGS.get(stem, ())
    return held[0] if len(held) == 1 else None


def scene_name(name: str) -> str:
    """The one accepted name of the scene ``name`` names (aliases resolved): an ETH/UCY
    split holding one recording is that recording (``ethucy:zara1`` ->
    ``ethucy:crowds_zara01``), ``sdd:<scene>_<N>`` is ``sdd:<scene>/video<N>``; any other
    name is returned as it is (:func:`load_scene` checks it).

    Parameters
    ----------
    name : str
        A scene name as typed.

    Raises
    ------
    InputError
        For ``ethucy:univ`` (two recordings: name one) or an unknown ETH/UCY recording.
    """
    if name.startswith("ethucy:"):
        stem, suffix = _ethucy_parts(name)
        rec = _recording_of(stem)
        if rec is None and stem in _SPLIT_RECORDINGS:
            both = " or ".join(f"ethucy:{r}{suffix}" for r in _SPLIT_RECORDINGS[stem])
            raise InputError(f"ethucy:{stem} is a split holding two recordings; name one: {both}")
        if rec is None:
            raise _unknown_ethucy(stem, name)
        return f"ethucy:{rec}{suffix}"
    if name.startswith("sdd:"):
        return sdd_video_name(name)
    return name


def sdd_video_name(name: str) -> str:
    """``sdd:<scene>_<N>`` as ``sdd:<scene>/video<N>`` (other names unchanged).

    Parameters
    ----------
    name : str
        An SDD name (``sdd:nexus_4`` or ``sdd:nexus/video4``, with an optional
        ``:trajnet`` / ``:raw`` form).
    """
    body, sep, form = name[len("sdd:") :].partition(":")
    m = _SDD_SHORT.match(body)
    if not name.startswith("sdd:") or m is None:
        return name
    return f"sdd:{m['scene']}/video{m['video']}{sep}{form}"


def ethucy_split(name: str) -> str:
    """The leave-one-out split (data folder) of an ETH/UCY name: a split as it is, a
    recording as the split it is the test recording of (``crowds_zara01`` -> ``zara1``,
    ``students001`` -> ``univ``).

    Parameters
    ----------
    name : str
        ``ethucy:<split or recording>`` or the bare split or recording.

    Raises
    ------
    InputError
        For a name that is neither.
    """
    stem = _ethucy_parts(name)[0] if name.startswith("ethucy:") else name.partition(":")[0]
    if stem in _SPLIT_RECORDINGS:
        return stem
    if stem in ETHUCY_RECORDINGS:
        return ETHUCY_RECORDINGS[stem]
    raise _unknown_ethucy(stem, name if name.startswith("ethucy:") else f"ethucy:{name}")


def dataset_name(name: str) -> str:
    """The one name of the data set ``name`` names (``eval-predictor`` and
    ``train-predictor``): ETH/UCY data sets are the leave-one-out splits, so a recording
    stands for its split (``ethucy:crowds_zara01`` -> ``ethucy:zara1``); anything else is
    the SDD scene whose tracks are the data set, by its scene name (:func:`scene_name`;
    ``sdd:nexus_4`` is the paper's scene ``nexus_4``, ``sdd:quad_2`` the video
    ``sdd:quad/video2``).

    Parameters
    ----------
    name : str
        A data set as typed.

    Raises
    ------
    InputError
        For one of univ's two recordings (the split holds both: name ``ethucy:univ``) or an
        unknown ETH/UCY name.
    """
    if not name.startswith("ethucy:"):
        kind, sep, rest = name.partition(":")
        if sep and kind == "sdd" and rest in scenes.PAPER_SCENES:
            return rest  # sdd:nexus_4: the paper's scene
        if sep and kind != "sdd" and not rest.startswith(("raw", "trajnet")):
            raise InputError(
                f"unknown data set kind {kind!r} in {name!r}; use ethucy:<recording or "
                "split> or sdd:<scene>/video<N> (or a scene name such as nexus_4)"
            )
        return scene_name(name)
    stem = _ethucy_parts(name)[0]
    split = ethucy_split(name)
    if stem in ETHUCY_RECORDINGS and len(_SPLIT_RECORDINGS[split]) > 1:
        raise InputError(
            f"{name} is one of the {len(_SPLIT_RECORDINGS[split])} recordings of the "
            f"leave-one-out split ethucy:{split}, which is evaluated and trained as a whole: "
            f"use ethucy:{split}"
        )
    return f"ethucy:{split}"


def _registered_or_close(name: str) -> bool:
    """Whether ``name`` is, or is close to, a registered scene (``nexsu_4``: the loader's
    own did-you-mean names ``nexus_4``)."""
    import difflib

    base = name.partition(":")[0]
    known = scenes.scene_names()
    return base in known or bool(difflib.get_close_matches(base, known, n=1, cutoff=0.6))


def fetch_selector(selector: str) -> str:
    """A ``fetch-data --only`` selector in the manifest's form: an ETH/UCY recording or
    split as its split's folder (``ethucy:crowds_zara01`` -> ``ethucy:zara1``), an SDD video
    or paper scene as ``sdd:<scene>_<N>`` (``sdd:nexus/video4`` -> ``sdd:nexus_4``); the
    rest (``sdd``, ``ethucy``, ``external...``) as it is.

    Parameters
    ----------
    selector : str
        The selector as typed.
    """
    kind, sep, name = selector.partition(":")
    if not sep or not name:
        return selector
    if kind == "ethucy":
        return f"ethucy:{ethucy_split(selector)}"
    if kind == "sdd":
        spec = scenes.PAPER_SCENES.get(name.partition(":")[0])
        if spec is not None:
            return f"sdd:{spec.sdd_scene}_{spec.video}"
        m = _SDD_LONG.match(sdd_video_name(selector)[len("sdd:") :].partition(":")[0])
        if m is not None:
            return f"sdd:{m['scene']}_{m['video']}"
    return selector


def suggest_scene(name: str) -> str | None:
    """The full name a bare recording or split name stands for (``zara1`` ->
    ``ethucy:crowds_zara01``, ``quad_2`` -> ``sdd:quad/video2``), or None.

    Parameters
    ----------
    name : str
        A scene name without its ``ethucy:`` / ``sdd:`` prefix.
    """
    if ":" in name:
        return None
    rec = _recording_of(name)
    if rec is not None:
        return f"ethucy:{rec}"
    if name in _SPLIT_RECORDINGS:
        return f"ethucy:{_SPLIT_RECORDINGS[name][0]}"
    m = _SDD_SHORT.match(name) or _SDD_LONG.match(name)
    if m is not None:
        return f"sdd:{m['scene']}/video{m['video']}"
    return None


def load_scene(
    name: str,
    data_root: str | os.PathLike[str] | None = None,
    *,
    start: Any = None,
    goals: Any = None,
    start_frame: int | None = None,
    v_max: float | None = None,
    history_frames: int = 120,
    seed: int = 0,
    last_frame: int | None = None,
    start_m: Sequence[float] | None = None,
    goals_m: Sequence[Sequence[float]] | None = None,
) -> Scene:
    """Build a scene by name.

    Parameters
    ----------
    name : str
        ``scenario:<suite>/<id>`` is a scenario of a shipped benchmark suite (its time
        limit in ``scene.meta["max_frames"]``; the other arguments but ``data_root`` do not
        apply); every other name is one of :func:`conformal_control.data.scenes.load_scene`
        (``crossing``, a paper scene, ``sdd:<scene>/video<N>``, ``ethucy:<recording>``),
        aliases resolved by :func:`scene_name`.
    data_root : path, optional
        Data folder (default ``$CONFORMAL_CONTROL_DATA``).
    start, goals, start_frame, v_max, history_frames, seed, last_frame, start_m, goals_m
        As in :func:`conformal_control.data.scenes.load_scene`.
    """
    if name.startswith("scenario:"):
        suite, _, sid = name[len("scenario:") :].partition("/")
        return load_scenario(shipped_scenario(suite, sid), data_root)
    suggestion = suggest_scene(name)
    if suggestion is not None and not _registered_or_close(name):
        raise InputError(
            f"unknown scene {name!r}; did you mean {suggestion!r}? (see `conformal-control scenes`)"
        )
    return scenes.load_scene(
        scene_name(name),
        data_root,
        start=start,
        goals=goals,
        start_frame=start_frame,
        v_max=v_max,
        history_frames=history_frames,
        seed=seed,
        last_frame=last_frame,
        start_m=start_m,
        goals_m=goals_m,
    )
