"""Foxglove's schemas as published, and the messages built from them."""

from __future__ import annotations

import hashlib
import json
import math

import pytest

from conformal_control.io.export import foxglove as fg


def test_foxglove_schemas_are_the_published_definitions():
    # sha256 of the definitions in foxglove/schemas (schemas/jsonschema, commit dd8b4f3)
    # without their "description" and "$comment" keys, as canonical JSON
    def canonical(o):
        if isinstance(o, dict):
            return {k: canonical(v) for k, v in o.items() if k not in ("description", "$comment")}
        return [canonical(v) for v in o] if isinstance(o, list) else o

    published = {
        "6741f9bf2c3daec271b1b034fa65f98dc04c5ff9f098974ed65b957b968f374a": fg.SCENE_UPDATE,
        "36bd77b42e2c10188ac0b93f0d8bdb1cc3e038311e1e732c53a4be0bd831148f": fg.FRAME_TRANSFORM,
        "831b6358d289bcc9e10dc126958de0aefee95f17747a22d8309f46581da5e354": fg.POSE_IN_FRAME,
    }
    for digest, schema in published.items():
        text = json.dumps(canonical(schema), sort_keys=True, separators=(",", ":"))
        assert hashlib.sha256(text.encode()).hexdigest() == digest, schema["title"]


def test_times_poses_and_entities():
    assert fg.time(12_345_678_901) == {"sec": 12, "nsec": 345_678_901}
    q = fg.yaw_quaternion(math.pi / 2)
    assert (q["z"], q["w"]) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    ent = fg.entity(5, "world", "e", cylinders=[fg.cylinder(1.0, 2.0, 0.6, 1.7, (1, 0, 0, 1))])
    assert set(ent) == set(fg.SCENE_UPDATE["properties"]["entities"]["items"]["properties"])
    assert ent["cylinders"][0]["pose"]["position"] == {"x": 1.0, "y": 2.0, "z": 0.85}
    with pytest.raises(TypeError, match="arrow"):
        fg.entity(0, "world", "e", arrow=[])
