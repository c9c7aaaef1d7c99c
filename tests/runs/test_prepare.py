"""``runs/prepare.py``: a run made ready from the front door's arguments, in one call."""

from __future__ import annotations

import warnings

import conformal_control as cc
from conformal_control.core.exceptions import ConformalControlDeprecationWarning
from conformal_control.runs.prepare import prepare_run


def test_the_settings_are_applied_once_so_a_deprecation_is_said_once():
    # a fallback among the safety filter's parameters (the way of 0.2) moves to the
    # fallback role with a warning: the run's settings are applied once, so it is said once
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = cc.run(
            "crossing",
            safety_filter="exact2d",
            safety_filter_params={"fallback": "brake"},
            max_frames=5,
            record_animation=False,
        )
    said = [w for w in caught if issubclass(w.category, ConformalControlDeprecationWarning)]
    assert len(said) == 1, [str(w.message) for w in said]
    assert res.config["spec"]["fallback"] == "brake"


def test_the_prepared_run_holds_its_spec_and_its_progress_totals():
    prepared = prepare_run("crossing", None, epsilon=-0.05, settings={"max_frames": 7})
    assert prepared.spec.params["epsilon"] == -0.05
    assert prepared.spec.units == "si"  # no dimensional parameter on an SI scene
    assert prepared.frames == 7  # the frame limit, below the scene's frames
    assert prepared.label == "run crossing [constant_velocity]"
    whole = prepare_run("crossing", None)
    sc = whole.scene
    assert whole.frames == sc.n_frames - 1 - sc.start_index
