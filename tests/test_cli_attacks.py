"""Every bad input a user can type or a broken file can hold, through the CLI.

Each case runs ``conformal-control`` in-process and checks: the exit status, exactly one
line on stderr that is one sentence starting ``error: `` (no traceback, no usage dump),
and the words that make the message useful (the offending value, a suggestion, the file
and line). Data cases use a temporary copy of a real SDD / ETH/UCY file, corrupted in
one place; nothing is ever written into the shared data folder. Accepted-but-odd data is
counted, never dropped silently.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from conformal_control.cli import EXIT_ERROR, main

NEXUS = Path("annotations/nexus/video4")


def one_error(capsys: pytest.CaptureFixture[str]) -> str:
    """stderr must be exactly one line, one sentence, ``error: ...``; returns it."""
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
    line = lines[0]
    assert line.startswith("error: "), line
    assert "Traceback" not in err and "internal error" not in line, line
    # one sentence: no sentence end followed by a new capitalised sentence
    assert not re.search(r"[.!?] +[A-Z][a-z]", line.removeprefix("error: ")), line
    return line


# ------------------------------------------------------------------------------ typed input
# (argv after "run", words the one-line error must contain)
TYPED = [
    ("scene typo", ["--scene", "nexsu_4"], ["unknown scene 'nexsu_4'", "did you mean 'nexus_4'"]),
    ("param typo", ["--param", "rho=400"], ["unknown parameter 'rho'", "did you mean 'rho0'"]),
    (
        "predictor param typo",
        ["--predictor-param", "windw=3"],
        ["no parameter 'windw'", "did you mean 'window'"],
    ),
    (
        "predictor typo",
        ["--predictor", "constant_velocty"],
        ["unknown predictor 'constant_velocty'", "did you mean 'constant_velocity'"],
    ),
    ("rule typo", ["--rule", "fixed_eat"], ["unknown rule 'fixed_eat'", "'fixed_eta'"]),
    ("rule param typo", ["--rule-param", "etta=1"], ["no parameter 'etta'", "'eta'"]),
    ("lambda-safe nan", ["--lambda-safe", "nan"], ["--lambda-safe", "finite"]),
    ("lambda-safe inf", ["--lambda-safe", "inf"], ["--lambda-safe", "finite"]),
    ("eta nan", ["--eta", "nan"], ["--eta", "finite"]),
    ("negative start frame", ["--start-frame", "-500"], ["--start-frame", ">= 0"]),
    ("zero frames", ["--frames", "0"], ["--frames", ">= 1"]),
    ("boolean as number", ["--param", "a=true"], ["parameter a must be a number", "boolean"]),
    ("boolean epsilon", ["--param", "epsilon=false"], ["epsilon", "boolean"]),
    ("delta nan", ["--param", "delta=nan"], ["delta must be a number in (0, 1)", "nan"]),
    ("delta too big", ["--param", "delta=1.5"], ["delta must be a number in (0, 1)"]),
    ("unit of wrong dimension", ["--param", "rho0=3s"], ["wrong unit 's'", "rho0 is a length"]),
    ("unknown unit", ["--param", "tau=3parsecs"], ["unknown unit", "tau is a time"]),
    ("pixels on an SI scene", ["--param", "rho0=40px"], ["no pixel scale"]),
    ("unit on a unitless parameter", ["--param", "epsilon=0.1m"], ["epsilon has no unit"]),
    ("text for a number", ["--param", "a=fast"], ["parameter a must be a number", "'fast'"]),
    ("param without value", ["--param", "a"], ["KEY=VALUE"]),
    ("start on the built-in scene", ["--start", "0.1,0.5"], ["fixed start"]),
    ("start not two numbers", ["--start", "0.1"], ["--start", "fx,fy"]),
    ("huge eta overflows lambda", ["--eta", "1e300/s"], ["lambda overflowed", "smaller eta"]),
    (
        "unknown option",
        ["--epsilonn", "0.1"],
        ["unknown option '--epsilonn'; did you mean '--epsilon'?"],
    ),
]


@pytest.mark.parametrize(("argv", "words"), [c[1:] for c in TYPED], ids=[c[0] for c in TYPED])
def test_typed_input(argv: list[str], words: list[str], tmp_path: Path, capsys) -> None:
    code = main(["run", "--out", str(tmp_path / "run"), "--no-plot", *argv])
    line = one_error(capsys)
    assert code == EXIT_ERROR
    for w in words:
        assert w in line, f"{w!r} not in {line!r}"
    assert not (tmp_path / "run").exists()  # nothing half-written


def test_unknown_command_suggests(capsys) -> None:
    assert main(["rnu"]) == EXIT_ERROR
    assert "did you mean 'run'" in one_error(capsys)


# ------------------------------------------------------------------------------ options
def test_sdd_video_needs_start_and_goal(sdd_dir: Path, tmp_path: Path, capsys) -> None:
    argv = ["run", "--scene", "sdd:quad/video2", "--data-root", str(sdd_dir)]
    assert main([*argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    line = one_error(capsys)
    assert "--start" in line and "--goal" in line


def _out_is_a_file(t: Path) -> Path:
    (t / "file").write_text("x")
    return t / "file"


def _out_below_a_file(t: Path) -> Path:
    (t / "f").write_text("x")
    return t / "f" / "sub" / "run"


@pytest.mark.parametrize(
    ("make", "words"),
    [(_out_is_a_file, "it is a file"), (_out_below_a_file, "is a file, not a folder")],
    ids=["out is a file", "out below a file"],
)
def test_unwritable_out_is_refused_before_running(
    make: Callable[[Path], Path], words: str, tmp_path: Path, capsys, monkeypatch
) -> None:
    import conformal_control.runs.engines.batch as engines  # the engine choice run() calls

    def no_run(*a: object, **k: object) -> None:
        raise AssertionError("the episode ran although --out cannot be written")

    monkeypatch.setattr(engines, "run_single", no_run)
    out = make(tmp_path)
    assert main(["run", "--out", str(out)]) == EXIT_ERROR
    assert words in one_error(capsys)


def test_config_that_is_a_folder_or_garbage(tmp_path: Path, capsys) -> None:
    (tmp_path / "bad.json").write_text("{not json")
    assert main(["run", "--config", str(tmp_path / "bad.json")]) == EXIT_ERROR
    assert "not valid JSON" in one_error(capsys)
    assert main(["run", "--config", str(tmp_path)]) == EXIT_ERROR  # folder without config
    assert "no such file" in one_error(capsys)


@pytest.mark.parametrize(
    ("stored", "words"),
    [
        ({"no_learning": "false"}, ["no_learning", "true or false", "'false'"]),
        ({"frames": "abc"}, ["frames", "abc"]),
        ({"frames": -3}, ["frames", "-3"]),
        ({"seed": 1.5}, ["seed", "1.5"]),
        ({"crowd": "stampede"}, ["crowd", "stampede"]),
        ({"goal": [[0.1, "x"]]}, ["goal", "0.1,x"]),
        ({"epsilon": {"a": 1}}, ["epsilon", "numbers or text"]),
    ],
)
def test_config_replay_is_type_checked(tmp_path: Path, capsys, stored, words) -> None:
    (tmp_path / "config.json").write_text(json.dumps({"cli": {"scene": "crossing", **stored}}))
    out = tmp_path / "out"
    assert main(["run", "--config", str(tmp_path), "--out", str(out)]) == EXIT_ERROR
    line = one_error(capsys)
    assert all(w in line for w in words), line
    assert not out.exists()


def test_config_replay_never_applies_an_output_folder(tmp_path: Path, capsys) -> None:
    """A config.json naming an output folder (or anything a run does not store) is not
    obeyed: the replay writes where this command line says, and says what it skipped."""
    victim = tmp_path / "victim"
    cfg = {"cli": {"scene": "crossing", "frames": 20, "out": str(victim), "no_plot": True}}
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    out = tmp_path / "mine"
    assert main(["run", "--config", str(tmp_path), "--out", str(out), "--no-plot"]) == 0
    assert not victim.exists() and (out / "metrics.json").exists()
    assert json.loads((out / "metrics.json").read_text())["frames"] <= 21
    err = capsys.readouterr().err
    assert "no_plot, out are not options a run stores" in err


def test_fetch_data_offline_is_one_line(tmp_path: Path, capsys) -> None:
    # port 9 on loopback refuses connections at once: the same path as an offline machine
    argv = ["fetch-data", "--dest", str(tmp_path / "d"), "--only", "sdd:nexus_4"]
    assert main([*argv, "--mirror", "http://127.0.0.1:9", "--quiet"]) == EXIT_ERROR
    line = one_error(capsys)
    assert "cannot download" in line and "--mirror" in line


def test_data_root_that_is_a_file(tmp_path: Path, capsys) -> None:
    (tmp_path / "data").write_text("not a folder")
    argv = ["run", "--scene", "nexus_4", "--data-root", str(tmp_path / "data")]
    assert main([*argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    assert "is a file; pass the data folder" in one_error(capsys)


def test_fetch_data_unknown_selection(tmp_path: Path, capsys) -> None:
    assert main(["fetch-data", "--dest", str(tmp_path), "--only", "sdd:nexsu_4"]) == EXIT_ERROR
    assert "matches no file" in one_error(capsys)


# ------------------------------------------------------------------------------ data
@pytest.fixture
def sdd_copy(sdd_dir: Path, tmp_path: Path) -> Path:
    """A private SDD folder with nexus_4 (annotations, image) and gates_1 (TrajNet)."""
    root = tmp_path / "sdd"
    (root / NEXUS).mkdir(parents=True)
    (root / "trajnet_pixels").mkdir()
    (root / "annotations/gates/video1").mkdir(parents=True)
    for rel in (
        "estimated_scales.yaml",
        NEXUS / "annotations.txt",
        NEXUS / "reference.jpg",
        "trajnet_pixels/gates_1.txt",
        "annotations/gates/video1/reference.jpg",
    ):
        shutil.copyfile(sdd_dir / rel, root / rel)
    return root


def _rewrite_line(path: Path, lineno: int, edit: Callable[[list[str]], list[str]]) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = " ".join(edit(lines[lineno - 1].split()))
    path.write_text("\n".join(lines) + "\n")


def _first_pedestrian_line(path: Path) -> int:
    for i, line in enumerate(path.read_text().splitlines(), start=1):
        if line.endswith('"Pedestrian"') and line.split()[6] == "0":
            return i
    raise AssertionError("no visible pedestrian row")


def _nan_box(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    k = _first_pedestrian_line(ann)
    _rewrite_line(ann, k, lambda p: [*p[:1], "nan", *p[2:]])
    return f"annotations.txt:{k}"


def _truncated_label(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    text = ann.read_text()
    cut = text.rindex('"Pedestrian"') + 3  # ... "Pe  (a download cut short)
    ann.write_text(text[:cut])
    return f"annotations.txt:{text[:cut].count(chr(10)) + 1}"


def _truncated_line(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    lines = ann.read_text().splitlines()
    lines[99] = " ".join(lines[99].split()[:4])
    ann.write_text("\n".join(lines) + "\n")
    return "annotations.txt:100"


def _non_numeric(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    _rewrite_line(ann, 7, lambda p: [p[0], "12a", *p[2:]])
    return "annotations.txt:7"


def _duplicate_trajnet_row(root: Path) -> str:
    tj = root / "trajnet_pixels/gates_1.txt"
    lines = tj.read_text().splitlines()
    lines.insert(11, lines[10])  # line 11 repeated as line 12
    tj.write_text("\n".join(lines) + "\n")
    frame, track = lines[10].split()[:2]
    return f"gates_1.txt:12: track {track} has a second row for frame {frame}"


def _image_not_an_image(root: Path) -> str:
    (root / NEXUS / "reference.jpg").write_text("this is not a jpeg")
    return "reference.jpg"


def _annotations_is_a_folder(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    ann.unlink()
    ann.mkdir()
    return "is a folder, not a file"


def _scales_not_yaml(root: Path) -> str:
    (root / "estimated_scales.yaml").write_text("nexus: [video4: {scale: ]\n")
    return "estimated_scales.yaml: not valid YAML"


def _trajnet_far_frame(root: Path) -> str:
    """One row at frame 2e9: the dense scene would need billions of frames (MemoryError)."""
    tj = root / "trajnet_pixels/gates_1.txt"
    _rewrite_line(tj, 30, lambda p: ["2000000004", *p[1:]])
    return "gates_1.txt:30: frame 2000000004 comes"


def _trajnet_off_grid(root: Path) -> str:
    tj = root / "trajnet_pixels/gates_1.txt"
    _rewrite_line(tj, 30, lambda p: [str(int(p[0]) + 5), *p[1:]])
    return "gates_1.txt:30: frame"


def _trajnet_huge_id(root: Path) -> str:
    tj = root / "trajnet_pixels/gates_1.txt"
    _rewrite_line(tj, 30, lambda p: [p[0], "1e20", *p[2:]])
    return "gates_1.txt:30: agent id 1e+20"


def _sdd_far_frame(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    k = _first_pedestrian_line(ann)
    _rewrite_line(ann, k, lambda p: [*p[:5], "2000000000", *p[6:]])
    return f"annotations.txt:{k}: frame 2000000000 comes"


def _sdd_huge_id(root: Path) -> str:
    ann = root / NEXUS / "annotations.txt"
    k = _first_pedestrian_line(ann)
    _rewrite_line(ann, k, lambda p: ["1e20", *p[1:]])
    return f"annotations.txt:{k}: agent id 1e+20"


DATA = [
    ("trajnet row at frame 2e9", "gates_1", _trajnet_far_frame, "probably wrong"),
    ("trajnet row off the frame grid", "gates_1", _trajnet_off_grid, "off the file's grid"),
    ("trajnet id of 1e20", "gates_1", _trajnet_huge_id, "not a whole number"),
    ("sdd row at frame 2e9", "nexus_4", _sdd_far_frame, "probably wrong"),
    ("sdd id of 1e20", "nexus_4", _sdd_huge_id, "not a whole number"),
    ("nan box coordinate", "nexus_4", _nan_box, "non-finite box coordinate"),
    ("truncated label", "nexus_4", _truncated_label, "is not a quoted name"),
    ("truncated line", "nexus_4", _truncated_line, "expected 10"),
    ("non-numeric field", "nexus_4", _non_numeric, "non-numeric"),
    ("duplicate trajnet row", "gates_1", _duplicate_trajnet_row, "gates_1.txt"),
    ("image is not an image", "nexus_4", _image_not_an_image, "cannot be read"),
    ("annotations is a folder", "nexus_4", _annotations_is_a_folder, "annotations.txt"),
    ("scales not yaml", "nexus_4", _scales_not_yaml, "line"),
]


@pytest.mark.parametrize(
    ("scene", "corrupt", "words"), [c[1:] for c in DATA], ids=[c[0] for c in DATA]
)
def test_corrupted_data_is_refused_with_file_and_line(
    scene: str, corrupt: Callable[[Path], str], words: str, sdd_copy: Path, tmp_path: Path, capsys
) -> None:
    where = corrupt(sdd_copy)
    code = main(
        ["run", "--scene", scene, "--data-root", str(sdd_copy), "--out", str(tmp_path / "r")]
    )
    line = one_error(capsys)
    assert code == EXIT_ERROR
    assert where in line and words in line, line


def test_other_labels_and_lost_rows_are_counted_not_dropped(
    sdd_copy: Path, tmp_path: Path, capsys
) -> None:
    ann = sdd_copy / NEXUS / "annotations.txt"
    text = ann.read_text().splitlines()
    n_other = sum(not ln.endswith('"Pedestrian"') for ln in text)
    n_lost = sum(ln.endswith('"Pedestrian"') and ln.split()[6] == "1" for ln in text)
    out = tmp_path / "r"
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_copy), "--frames", "30"]
    assert main([*argv, "--out", str(out), "--no-plot", "--quiet"]) == 0
    scene = json.loads((out / "config.json").read_text())["scene"]
    assert scene["n_other_label_rows"] == n_other > 0
    assert scene["n_lost_rows"] == n_lost > 0
    assert scene["n_rows"] + n_other + n_lost == len(text)


def test_ethucy_file_that_is_a_folder(ethucy_dir: Path, tmp_path: Path, capsys) -> None:
    root = tmp_path / "ethucy"
    shutil.copytree(ethucy_dir / "zara1" / "test", root / "zara1" / "test")
    for other in ("eth", "hotel", "univ"):
        (root / other).mkdir()
    (root / "zara1" / "test" / "extra.txt").mkdir()
    argv = ["eval-predictor", "--predictor", "constant_velocity", "--dataset", "ethucy:zara1"]
    assert main([*argv, "--data-root", str(root)]) == EXIT_ERROR
    line = one_error(capsys)
    assert "extra.txt" in line and "is a folder, not a file" in line


# ------------------------------------------------------------------------------ code in files
class _WritesMarker:
    """Unpickling this object writes a file: the proof that loading ran code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[Path, str]]:
        return (Path.write_text, (self.marker, "code ran"))


def test_weights_folder_with_a_pickle_runs_no_code(tmp_path: Path, capsys) -> None:
    """A config or sweep spec naming ``weights=<folder>`` must not execute the folder."""
    import pickle

    folder = tmp_path / "weights"
    folder.mkdir()
    params = {"estimator": "Ridge", "estimator_params": None, "obs": 8, "horizon": 12}
    params |= {"model_dt": 0.4, "weights": None, "random_state": 0}
    (folder / "config.json").write_text(json.dumps({"class": "SklearnPredictor", "params": params}))
    marker = tmp_path / "pwned"
    (folder / "model.joblib").write_bytes(pickle.dumps(_WritesMarker(marker)))
    argv = ["run", "--predictor", "sklearn", "--predictor-param", f"weights={folder}"]
    assert main([*argv, "--out", str(tmp_path / "r"), "--no-plot"]) == EXIT_ERROR
    line = one_error(capsys)
    assert "a pickle of an older version, which is not loaded" in line
    assert not marker.exists()


# ------------------------------------------------------------------------------ the step-wise API
def _stepwise(**kw: object) -> object:
    from conformal_control.families.cbf import StepwiseCBF, Stream

    return StepwiseCBF("constant_velocity", stream=Stream(tau=0.4, dt=0.1), **kw)


def _observed(*samples: tuple[list[object], list[list[float]], float]) -> None:
    ctrl = _stepwise()
    for ids, pos, t in samples:
        ctrl.observe(ids, pos, t=t)


def _steps(per_sample: int, spacing: float) -> None:
    import numpy as np

    ctrl = _stepwise()
    for k in range(3):
        ctrl.observe([0], [[10.0, 3.0]], t=k * 0.1)
        for j in range(per_sample):
            ctrl.step(np.zeros(4), t=k * 0.1 + j * spacing, goal=[20.0, 0.0])


def _step_at(t: float) -> None:
    import numpy as np

    ctrl = _stepwise()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=[20.0, 0.0])
    ctrl.step(np.zeros(4), t=t, goal=[20.0, 0.0])


def _goal(goal: list[float]) -> None:
    import numpy as np

    ctrl = _stepwise()
    ctrl.observe([0], [[10.0, 3.0]], t=0.0)
    ctrl.step(np.zeros(4), t=0.0, goal=goal)


# (name, call, words of the one-sentence ValueError)
STEPWISE: list[tuple[str, Callable[[], object], list[str]]] = [
    ("duplicate ids", lambda: _observed(([7, 7], [[5.0, 0.0], [3.0, 0.0]], 0.0)), ["id 7"]),
    ("float id", lambda: _observed(([1.5], [[5.0, 0.0]], 0.0)), ["whole numbers", "1.5"]),
    ("id of 1e20", lambda: _observed(([1e20], [[5.0, 0.0]], 0.0)), ["too large"]),
    ("epsilon 5", lambda: _stepwise(epsilon=5.0), ["epsilon must lie in (-1/2, 1/2)"]),
    (
        "2 steps per sample",
        lambda: _steps(2, 0.05),
        ["step() at t = 0.05 s, expected t = 0.025 s", "4 times"],
    ),
    ("8 steps per sample", lambda: _steps(8, 0.0125), ["expected t = 0.025 s"]),
    ("step at t = -5", lambda: _step_at(-5.0), ["expected t = 0.025 s"]),
    ("step at t = nan", lambda: _step_at(float("nan")), ["t must be finite"]),
    ("step at t = 1e9", lambda: _step_at(1e9), ["expected t = 0.025 s"]),
    (
        "observe twice at one t",
        lambda: _observed(([0], [[5.0, 0.0]], 0.0), ([1], [[3.0, 0.0]], 0.0)),
        ["already observed"],
    ),
    ("observe at t = nan", lambda: _observed(([0], [[5.0, 0.0]], float("nan"))), ["finite"]),
    ("goal of 3 numbers", lambda: _goal([1.0, 2.0, 3.0]), ["goal must be 2 finite numbers"]),
]


@pytest.mark.parametrize(("call", "words"), [c[1:] for c in STEPWISE], ids=[c[0] for c in STEPWISE])
def test_stepwise_input_contract(call: Callable[[], object], words: list[str]) -> None:
    with pytest.raises(ValueError) as info:
        call()
    message = str(info.value)
    assert "\n" not in message and not re.search(r"[.!?] +[A-Z][a-z]", message), message
    for w in words:
        assert w in message, f"{w!r} not in {message!r}"


# ------------------------------------------------------------------------------ ETH/UCY rows
@pytest.fixture
def zara_copy(ethucy_dir: Path, tmp_path: Path) -> Path:
    root = tmp_path / "ethucy"
    shutil.copytree(ethucy_dir / "zara1" / "test", root / "zara1" / "test")
    for other in ("eth", "hotel", "univ"):
        (root / other).mkdir()
    return root


def _zara_rows(root: Path) -> tuple[Path, list[str]]:
    path = root / "zara1" / "test" / "crowds_zara01.txt"
    return path, path.read_text().splitlines()


def _eval(root: Path) -> int:
    argv = ["eval-predictor", "--predictor", "constant_velocity", "--dataset", "ethucy:zara1"]
    return main([*argv, "--data-root", str(root)])


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda f: [str(float(f[0]) + 3), *f[1:]], "is off the file's grid of one sample every 10"),
        (lambda f: ["2000000000", *f[1:]], "comes"),
        (lambda f: [f[0], "1e20", *f[2:]], "agent id 1e+20 is not a whole number"),
    ],
    ids=["off-grid frame", "frame 2e9", "id of 1e20"],
)
def test_ethucy_bad_row_is_one_line_with_file_and_line(
    edit: Callable[[list[str]], list[str]], words: str, zara_copy: Path, capsys
) -> None:
    """An off-grid row used to become the file's time step: every pedestrian 3.3x slower."""
    path, lines = _zara_rows(zara_copy)
    lines[40] = " ".join(edit(lines[40].split()))
    path.write_text("\n".join(lines) + "\n")
    assert _eval(zara_copy) == EXIT_ERROR
    line = one_error(capsys)
    assert "crowds_zara01.txt:41" in line and words in line, line


def test_ethucy_duplicate_rows_are_counted_or_refused(zara_copy: Path, capsys) -> None:
    from conformal_control.data.ethucy import read_ethucy

    path, lines = _zara_rows(zara_copy)
    clean = read_ethucy(path)
    assert clean.meta["n_duplicate_rows"] == 0
    path.write_text("\n".join([*lines[:41], lines[40], *lines[41:]]) + "\n")  # repeated
    again = read_ethucy(path)
    assert again.meta["n_duplicate_rows"] == 1 and again.meta["n_rows"] == len(lines) + 1
    for i, (f, xy) in clean.tracks.items():
        np.testing.assert_array_equal(again.tracks[i][0], f)
        np.testing.assert_array_equal(again.tracks[i][1], xy)
    moved = lines[40].split()
    moved[2] = str(float(moved[2]) + 1.0)
    path.write_text("\n".join([*lines[:41], " ".join(moved), *lines[41:]]) + "\n")
    assert _eval(zara_copy) == EXIT_ERROR
    line = one_error(capsys)
    assert "crowds_zara01.txt:42" in line and "second, different position" in line, line
    assert "first at line 41" in line


# ------------------------------------------------------------------------------ disks
def test_a_full_disk_names_the_file_and_leaves_no_truncated_one(tmp_path: Path) -> None:
    """Files cut off by a full disk (here: a 4 KiB file-size limit) used to stay behind,
    truncated or empty, with an error that named no path."""
    import subprocess
    import sys

    code = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail (EFBIG)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
        "from conformal_control.cli import main\n"
        "sys.exit(main())\n"
    )
    out = tmp_path / "r"
    argv = ["run", "--frames", "20", "--no-plot", "--quiet", "--out", str(out)]
    res = subprocess.run(
        [sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=600
    )
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error: ")]
    assert res.returncode == EXIT_ERROR and len(errors) == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert f"cannot write {out}" in errors[0] and "size limit" in errors[0], errors[0]
    for path in out.rglob("*"):
        assert not path.name.endswith(".tmp"), path
        if path.suffix == ".json":
            json.loads(path.read_text())  # complete, never cut off
    assert not (out / "metrics.json").exists()  # the run directory is not marked complete


# ------------------------------------------------------------------------------ smaller files
def _scales(root: Path, edit: Callable[[str], str]) -> None:
    path = root / "estimated_scales.yaml"
    path.write_text(edit(path.read_text()))


def _nexus_scale(value: str) -> Callable[[str], str]:
    def edit(text: str) -> str:
        head, _, tail = text.partition("nexus:")
        before, _, after = tail.partition("video4:")
        scale_line = after.split("\n", 2)
        return head + "nexus:" + before + "video4:\n      scale: " + value + "\n" + scale_line[2]

    return edit


def _bomb(root: Path) -> None:
    """A PNG header claiming 60000 x 60000 pixels: 3.6 billion, from 57 bytes."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b"")
    (root / NEXUS / "reference.jpg").write_bytes(png)


SMALLER = [
    ("scale 0", lambda r: _scales(r, _nexus_scale("0")), "scale in metres per pixel > 0"),
    ("scale nan", lambda r: _scales(r, _nexus_scale(".nan")), "scale in metres per pixel > 0"),
    (
        "scene not a mapping",
        lambda r: _scales(r, lambda t: "nexus: [1, 2]\n" + t.split("nexus:")[0]),
        "scene nexus must map videoN",
    ),
    (
        "video entry not a mapping",
        lambda r: _scales(r, _nexus_scale("0.04\n      x: [")),
        "estimated_scales.yaml",
    ),
    ("decompression bomb image", _bomb, "decompression bomb"),
]


@pytest.mark.parametrize(
    ("corrupt", "words"), [c[1:] for c in SMALLER], ids=[c[0] for c in SMALLER]
)
def test_smaller_data_attacks(
    corrupt: Callable[[Path], None], words: str, sdd_copy: Path, tmp_path: Path, capsys
) -> None:
    corrupt(sdd_copy)
    argv = ["run", "--scene", "nexus_4", "--data-root", str(sdd_copy), "--no-plot"]
    assert main([*argv, "--out", str(tmp_path / "r")]) == EXIT_ERROR
    line = one_error(capsys)
    assert words in line, line


def _deep(path: Path, opener: str = "[", closer: str = "]") -> Path:
    path.write_text(opener * 50_000 + closer * 50_000)
    return path


DEEP = [
    ("sweep spec json", lambda t: ["sweep", str(_deep(t / "s.json")), "--dry-run"], "sweep spec"),
    (
        "run config",
        lambda t: ["run", "--config", str(_deep(t / "c.json", '{"a":', "}"))],
        "--config",
    ),
    (
        "robots file",
        lambda t: ["run", "--robots-file", str(_deep(t / "r.json")), "--no-plot"],
        "robots file",
    ),
    (
        "sweep spec base not a mapping",
        lambda t: ["sweep", str(_text(t / "s.yaml", "base: [1, 2]\n")), "--dry-run"],
        "'base' of the sweep spec must be a mapping",
    ),
    (
        "sweep spec grid not a mapping",
        lambda t: ["sweep", str(_text(t / "s.yaml", "grid: [1, 2]\n")), "--dry-run"],
        "'grid' of the sweep spec must be a mapping",
    ),
    ("bench run --limit -1", lambda t: ["bench", "run", "--limit", "-1"], "--limit"),
    ("bench run -j 0", lambda t: ["bench", "run", "-j", "0"], "-j/--workers"),
    ("sweep -j 0", lambda t: ["sweep", "--scene", "crossing", "-j", "0"], "-j/--workers"),
]


def _text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize(("make", "words"), [c[1:] for c in DEEP], ids=[c[0] for c in DEEP])
def test_nested_or_nonsensical_inputs(
    make: Callable[[Path], list[str]], words: str, tmp_path: Path, capsys
) -> None:
    argv = make(tmp_path)
    assert main([*argv, "--out", str(tmp_path / "o")]) == EXIT_ERROR
    line = one_error(capsys)
    assert words in line, line


ROBOTS = [
    (
        "unknown top-level key",
        {"robots": [{"start": [1, 1], "goal": [9, 9]}], "unit": "m"},
        "unknown key 'unit' at the top level; did you mean 'units'",
    ),
    (
        "unknown robot key",
        {"robots": [{"start": [1, 1], "goall": [9, 9], "goal": [9, 9]}]},
        "unknown key 'goall' in robot 0",
    ),
    (
        "fraction above 1",
        {"units": "fraction", "robots": [{"start": [0.1, 1.5], "goal": [0.9, 0.5]}]},
        "fraction outside [0, 1]",
    ),
    (
        "fraction below 0",
        {"units": "fraction", "robots": [{"start": [0.1, 0.5], "goal": [-0.2, 0.5]}]},
        "fraction outside [0, 1]",
    ),
    (
        "identical starts",
        {"robots": [{"start": [2, 3], "goal": [9, 3]}, {"start": [2, 3], "goal": [9, 5]}]},
        "robots 0 and 1 start 0 m apart",
    ),
]


@pytest.mark.parametrize(("spec", "words"), [c[1:] for c in ROBOTS], ids=[c[0] for c in ROBOTS])
def test_robots_file_attacks(spec: dict, words: str, tmp_path: Path, capsys) -> None:
    path = tmp_path / "robots.json"
    path.write_text(json.dumps(spec))
    argv = ["run", "--robots-file", str(path), "--no-plot", "--out", str(tmp_path / "o")]
    assert main(argv) == EXIT_ERROR
    line = one_error(capsys)
    assert words in line, line
