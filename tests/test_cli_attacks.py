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
    ("rule typo", ["--rule", "fixed_eat"], ["unknown update_rule 'fixed_eat'", "'fixed_eta'"]),
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
    ("unknown option", ["--epsilonn", "0.1"], ["unrecognized arguments: --epsilonn"]),
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
    import conformal_control.sim.episode as episode

    def no_run(*a: object, **k: object) -> None:
        raise AssertionError("the episode ran although --out cannot be written")

    monkeypatch.setattr(episode, "run_episode", no_run)
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


DATA = [
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
