"""Kernels run interpreted until a process has work enough to compile them, with the same
numbers either way (``conformal_control.core.jit``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conformal_control.core import jit

DATA = Path(
    os.environ.get("CONFORMAL_CONTROL_DATA", Path(__file__).parents[2] / ".." / "shared" / "data")
)

#: Episodes and kernel calls of every compiled path, dumped field by field (run twice in
#: fresh interpreters: interpreted, then compiled).
_EPISODES = r"""
import hashlib, json, sys, warnings
import numpy as np
warnings.simplefilter("ignore")
from conformal_control.core import jit
from conformal_control.data import load_scene
from conformal_control.data.synthetic import crossing_scene
from conformal_control.runs.engines.batch import run_batch
from conformal_control.runs.episode import run_episode

def digest(a):
    a = np.ascontiguousarray(np.asarray(a, dtype=float))
    return hashlib.sha256(a.tobytes()).hexdigest()[:16] + str(a.shape)

def result(r):
    out = {k: repr(v) for k, v in r.metrics.as_dict().items() if k != "wall_s"}
    out["trajectory"] = {k: digest(v) for k, v in r.trajectory.items()}
    out["steps"] = {k: digest(v) for k, v in (r.steps or {}).items()}
    out["intervals"] = json.dumps(r.intervals, sort_keys=True, default=repr)
    return out

out = {}
scenes = [crossing_scene(seed=s, duration=8.0) for s in range(3)]
for fb in ("lambda_search", "brake", "hold"):
    for engine in ("loop", "batch"):
        out[f"crossing-{fb}-{engine}"] = [
            result(run_episode(sc, "constant_velocity", {"epsilon": -0.05}, fallback=fb,
                               engine=engine, record_animation=False))
            for sc in scenes
        ]
out["batch-metrics"] = [
    {k: repr(v) for k, v in m.as_dict().items() if k != "wall_s"}
    for m in run_batch(scenes, "constant_velocity", batch_size=2)
]
out["oracle-loss"] = [
    {k: repr(v) for k, v in m.as_dict().items() if k != "wall_s"}
    for m in run_batch(scenes, "oracle", loss="distance_shortfall")
]
for shift, prm in (("dropout", {"p": 0.3}), ("noisy", {"sigma_m": 0.25}),
                   ("delayed", {"delay_s": 0.5})):  # the shifts' compiled prediction
    out[f"shift-{shift}"] = [
        {k: repr(v) for k, v in m.as_dict().items() if k != "wall_s"}
        for m in run_batch(scenes, shift, predictor_params=prm, seeds=[5, 6, 7])
    ]
rows, pos = ["frame,track_id,step,x,y"], scenes[0].positions  # recorded forecasts
for f in range(0, pos.shape[0], 5):
    for j in range(pos.shape[1]):
        for s in range(1, 9 if j % 3 else 4):  # some end early: extrapolated
            g = f + 3 * s
            if g < pos.shape[0] and np.isfinite(pos[[f, g], j]).all() and (f + j + s) % 7:
                x, y = (pos[g, j] + 0.1 * np.sin([f + j, s])).tolist()
                rows.append(f"{f},{int(scenes[0].agent_ids[j])},{s},{x!r},{y!r}")
open(sys.argv[1] + ".csv", "w").write("\n".join(rows) + "\n")
prm = {"path": sys.argv[1] + ".csv", "step_s": 0.3, "frames_per_step": 3.0}
out["recorded"] = [
    {k: repr(v) for k, v in m.as_dict().items() if k != "wall_s"}
    for m in run_batch(scenes, "recorded", predictor_params=prm)
]
out["orca"] = result(run_episode(scenes[2], "constant_velocity", crowd="orca", max_frames=50))
out["social_force"] = result(run_episode(scenes[1], "constant_velocity", crowd="social_force",
                                         max_frames=50))
nexus = load_scene("nexus_4", sys.argv[2])
out["nexus_4-loop"] = result(run_episode(nexus, "constant_velocity", engine="loop"))
out["nexus_4-batch"] = result(run_episode(nexus, "constant_velocity", engine="batch"))

from conformal_control.families.cbf.dynamics import Unicycle, VelocityTrackingDoubleIntegrator
rng = np.random.default_rng(0)
cmds = rng.normal(0, 1, (5, 7, 2))
vt = VelocityTrackingDoubleIntegrator(K_acc=10.0)
out["rollouts"] = [
    digest(vt.rollout(np.array([0.0, 0, 1, 0]), cmds, 0.05)),
    digest(Unicycle().rollout(np.array([0.0, 0, 0.3, 0.5, 0.2]), cmds, 0.05)),
]
from conformal_control.families.mpc.kernels import evaluate
pos = rng.normal(0, 3, (50, 6, 2)); c2 = rng.normal(0, 1, (50, 6, 2))
pred = rng.normal(0, 3, (7, 6, 2)); y0 = rng.normal(0, 3, (7, 2))
radius = rng.uniform(0.5, 1.5, (50, 6))
out["mpc"] = [
    digest(a) for cont in (True, False)
    for a in evaluate(pos, c2, np.zeros(2), pred, y0, radius, np.array([4.0, 1.0]),
                      (1.0, 10.0, 0.01, 0.3), np.array([0.2, -0.1]), cont)
]
from conformal_control.runs.fleet import run_multi
for info in ("position", "velocity", "plan"):  # reciprocal robot rows (cbf.kernels_peers)
    res = run_multi(scenes[0], robots=4, layout="antipodal", radius=3.0, center=(15.0, 8.0),
                    information=info, max_frames=60, record_animation=False)
    out[f"multi-{info}"] = [digest(res.track["robots"])] + [
        result(r) for r in res.robots
    ]
out["compiled"] = jit.is_compiled()
out["numba_imported"] = "numba" in sys.modules
json.dump(out, open(sys.argv[1], "w"), sort_keys=True)
"""


def _run(code: str, env_mode: str, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "CONFORMAL_CONTROL_JIT": env_mode}
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )


def test_interpreted_and_compiled_runs_are_identical(tmp_path: Path) -> None:
    if not (DATA / "sdd").is_dir():
        raise AssertionError(f"the SDD data is missing: expected it at {DATA}")
    dumps = {}
    for mode in ("never", "always"):
        out = tmp_path / f"{mode}.json"
        proc = _run(_EPISODES, mode, str(out), str(DATA))
        assert proc.returncode == 0, proc.stderr[-3000:]
        dumps[mode] = json.loads(out.read_text())
    never, always = dumps["never"], dumps["always"]
    assert never.pop("compiled") is False and always.pop("compiled") is True
    assert never.pop("numba_imported") is False  # interpreted: numba never imported
    always.pop("numba_imported")
    assert never.keys() == always.keys()
    for key in never:
        assert never[key] == always[key], key


_AUTO = r"""
import json, sys
import numpy as np
from conformal_control.core import jit
from conformal_control.families.cbf import kernels2d
jit.BUDGET_S = float(sys.argv[1])
A = np.array([[1.0, 0.0]]); rhs = np.array([2.0]); G = np.zeros((4, 2)); h = np.zeros(4)
before = type(kernels2d.presolve).__name__
first = kernels2d.presolve(A, rhs, 1.0, G, h)  # with no budget, compiles once it returns
for _ in range(int(sys.argv[2])):
    again = kernels2d.presolve(A, rhs, 1.0, G, h)
print(json.dumps([first, again, before, type(kernels2d.presolve).__name__, jit.is_compiled(),
                  "numba" in sys.modules]))
"""


def test_auto_interprets_until_the_budget_then_compiles() -> None:
    # a large budget: interpreted throughout, numba never imported
    proc = _run(_AUTO, "auto", "1000", "3")
    assert proc.returncode == 0, proc.stderr
    first, again, before, after, compiled, numba = json.loads(proc.stdout)
    assert (before, after, compiled, numba) == ("Kernel", "Kernel", False, False)
    assert first == again
    # no budget: the first call pays it; the module's name is numba's dispatcher from then on
    proc = _run(_AUTO, "auto", "0", "1")
    assert proc.returncode == 0, proc.stderr
    first, again, before, after, compiled, numba = json.loads(proc.stdout)
    assert before == "Kernel" and after == "CPUDispatcher" and compiled and numba
    assert first == again


def test_never_stays_interpreted_and_always_compiles_at_once() -> None:
    proc = _run(_AUTO, "never", "0", "2")
    assert json.loads(proc.stdout)[3:5] == ["Kernel", False]
    proc = _run(_AUTO, "always", "1000", "1")
    assert json.loads(proc.stdout)[3:5] == ["CPUDispatcher", True]


def test_a_short_run_from_the_command_line_imports_no_numba(tmp_path: Path) -> None:
    out = str(tmp_path / "r")
    code = (
        "import contextlib, io, sys\n"
        "from conformal_control.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    main(['run', '--no-plot', '-q', '--frames', '60', '--out', {out!r}])\n"
        "print(sorted(m for m in ('numba', 'scipy', 'llvmlite') if m in sys.modules))\n"
    )
    proc = _run(code, "auto")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "r" / "metrics.json").is_file()


def test_the_mode_is_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    for value, want in (("", "auto"), (" Always ", "always"), ("never", "never")):
        monkeypatch.setenv("CONFORMAL_CONTROL_JIT", value)
        assert jit.mode() == want
    monkeypatch.setenv("CONFORMAL_CONTROL_JIT", "sometimes")
    with pytest.raises(ValueError, match="CONFORMAL_CONTROL_JIT must be one of auto"):
        jit.mode()


def test_a_kernel_looks_like_its_function() -> None:
    from conformal_control.families.cbf import kernels2d

    k = kernels2d.presolve
    assert k.__name__ == "presolve" and "unit-norm" in (k.__doc__ or "")
    assert callable(k.py_func) and k.py_func.__name__ == "presolve"
