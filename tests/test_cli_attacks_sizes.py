"""Size bombs: every reader has a cap stated in its error, every size parameter a range
checked before anything is allocated, and a FIFO or a device is refused, never read.

Before: a recorded-predictions row with step 1e11 asked for 1.46 TiB; a 25 KB file took
640 MB (issue frames x the file's longest step); a 204 KB gzip file decompressed to
gigabytes and a corrupt one was an internal error; ``run --config /dev/zero`` and
``--robots-file /dev/zero`` read until memory ran out and a FIFO as ``--config`` hung;
``--param substeps=1e8`` asked for 95 GiB, ``speed_sides=1e8`` ran for minutes; the MPC's
``sampling__n_samples=1e9`` asked for 44.7 GiB and ``sampling__horizon=100000`` ran for
minutes."""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import pytest

from conformal_control.cli import EXIT_ERROR, main


def _run(tmp_path: Path, *argv: str) -> int:
    out = ["run", "--scene", "crossing", "--frames", "5", "--no-plot", "--quiet"]
    return main([*out, "--out", str(tmp_path / "r"), *argv])


def _recorded(tmp_path: Path, file: Path) -> int:
    return _run(
        tmp_path,
        "--predictor",
        "recorded",
        "--predictor-param",
        f"path={file}",
        "--predictor-param",
        "frames_per_step=1",
    )


# ------------------------------------------------------------------------------ parameters
PARAMS = [
    ("speed_sides 1e8", ["--param", "speed_sides=100000000"], "from 3 to 1024"),
    ("substeps 1e8", ["--param", "substeps=100000000"], "substeps must be an integer in [1, 100]"),
    ("history 1e9", ["--param", "history=1000000000"], "history must be an integer in [1, 100000]"),
    (
        "mpc n_samples 1e9",
        ["--family", "mpc", "--family-param", "sampling__n_samples=1e9"],
        "n_samples must be an integer from 1 to 100,000",
    ),
    (
        "mpc horizon 1e5",
        ["--family", "mpc", "--family-param", "sampling__horizon=100000"],
        "horizon must be an integer from 1 to 1,000",
    ),
    (
        "mpc plan points",
        [
            "--family",
            "mpc",
            "--family-param",
            "sampling__n_samples=100000",
            "--family-param",
            "sampling__horizon=1000",
        ],
        "n_samples x horizon must be at most 2,000,000 plan points",
    ),
    (
        "mpc substeps 1e8",
        ["--family", "mpc", "--family-param", "substeps=100000000"],
        "substeps must be an integer from 1 to 100",
    ),
]


@pytest.mark.parametrize(("argv", "words"), [c[1:] for c in PARAMS], ids=[c[0] for c in PARAMS])
def test_a_size_parameter_out_of_its_range_is_refused_before_allocating(
    argv: list[str], words: str, tmp_path: Path, error_line
) -> None:
    assert _run(tmp_path, *argv) == EXIT_ERROR
    assert words in error_line()
    assert not (tmp_path / "r" / "metrics.json").exists()


# ------------------------------------------------------------------------------ recorded files
def test_a_far_step_is_refused(tmp_path: Path, error_line) -> None:
    f = tmp_path / "p.csv"
    f.write_text("frame,track_id,step,x,y\n0,1,100000000000,1,1\n")
    assert _recorded(tmp_path, f) == EXIT_ERROR
    assert "step 100000000000 is beyond 1000, the longest forecast read" in error_line()


def test_memory_follows_the_rows_not_the_longest_step(tmp_path: Path) -> None:
    """One forecast of 1,000 steps among 1,200 one-step ones: every issue frame's array
    used to be as wide as the longest (1,200 x 1,000 points)."""
    from conformal_control.predictors.recorded import read_predictions

    rows = ["frame,track_id,step,x,y", *(f"{10 * f},1,1,0,0" for f in range(1200))]
    rows.append("0,1,1000,5,5")
    (tmp_path / "p.csv").write_text("\n".join(rows) + "\n")
    rec = read_predictions(tmp_path / "p.csv")
    assert sum(p.shape[1] for p in rec.points) == 1199 + 1000
    assert rec.points[0][0, 999].tolist() == [5.0, 5.0]


def test_a_gzip_bomb_is_capped_and_says_so(tmp_path: Path, monkeypatch, error_line) -> None:
    import conformal_control.predictors.recorded as recorded

    monkeypatch.setattr(recorded, "MAX_FILE_BYTES", 1 << 20)  # 1 MiB, for a fast test
    recorded._CACHE.clear()
    f = tmp_path / "bomb.csv.gz"
    with gzip.open(f, "wb") as g:
        g.write(b"frame,track_id,step,x,y\n" + b"0" * (4 << 20))
    assert f.stat().st_size < 20_000
    assert _recorded(tmp_path, f) == EXIT_ERROR
    assert "decompresses to more than 1 MiB, the most read" in error_line()


def test_a_corrupt_gzip_file_is_one_line(tmp_path: Path, error_line) -> None:
    raw = b"frame,track_id,step,x,y\n" + b"".join(
        f"{f},{i},{s},{f * 0.1},{i}\n".encode()
        for f in range(0, 400, 10)
        for i in range(5)
        for s in range(1, 13)
    )
    data = bytearray(gzip.compress(raw))
    for k in range(40, 60):
        data[k] ^= 0xFF
    f = tmp_path / "bad.csv.gz"
    f.write_bytes(bytes(data))
    assert _recorded(tmp_path, f) == EXIT_ERROR
    assert "is not a valid gzip file" in error_line()


def test_a_plain_file_over_the_cap_is_refused(tmp_path: Path, monkeypatch, error_line) -> None:
    import conformal_control.predictors.recorded as recorded

    monkeypatch.setattr(recorded, "MAX_FILE_BYTES", 1 << 10)
    recorded._CACHE.clear()
    f = tmp_path / "p.csv"
    f.write_text("frame,track_id,step,x,y\n" + "0,1,1,0,0\n" * 200)
    assert _recorded(tmp_path, f) == EXIT_ERROR
    assert "is larger than 1 KiB, the most read" in error_line()


# ------------------------------------------------------------------------------ FIFOs, devices
@pytest.mark.parametrize("option", ["--config", "--robots-file", "predictions"])
@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_fifo_or_a_device_is_refused_not_read(
    option: str, kind: str, tmp_path: Path, error_line
) -> None:
    if kind == "fifo":
        node = tmp_path / "node"
        os.mkfifo(node)  # reading it would wait for a writer forever
    else:
        node = Path("/dev/zero")  # reading it would never end
    if option == "predictions":
        code = _recorded(tmp_path, node)
    else:
        code = _run(tmp_path, option, str(node))
    assert code == EXIT_ERROR
    line = error_line()
    assert f"{node} is {'a FIFO' if kind == 'fifo' else 'a device'}" in line


def test_a_data_file_that_is_a_fifo_is_refused(ethucy_dir: Path, tmp_path: Path, error_line):
    import shutil

    root = tmp_path / "ethucy"
    shutil.copytree(ethucy_dir / "zara1" / "test", root / "zara1" / "test")
    for other in ("eth", "hotel", "univ"):
        (root / other).mkdir()
    target = next((root / "zara1" / "test").glob("*.txt"))
    target.unlink()
    os.mkfifo(target)
    argv = ["eval-predictor", "--predictor", "constant_velocity", "--dataset", "ethucy:zara1"]
    assert main([*argv, "--data-root", str(root)]) == EXIT_ERROR
    line = error_line()
    assert str(target) in line and "not a regular file" in line
