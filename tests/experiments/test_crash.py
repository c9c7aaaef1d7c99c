"""Attacks on a real sweep process: kills at random points, SIGTERM, two sweeps on one folder.

Each sweep here is a ``conformal-control sweep`` subprocess on the process pool, so the
kills are real. Every process a test starts carries a unique environment token, which
its pool workers, fork server and resource tracker inherit: "no process left behind"
means no live process with that token.
"""

from __future__ import annotations

import csv
import json
import os
import random
import signal
import subprocess
import sys
import time
import uuid
from collections import Counter
from pathlib import Path

from conformal_control.cli import main
from conformal_control.experiments import SweepSpec

TOKEN = "CONFORMAL_CONTROL_TEST_SWEEP_TOKEN"
CLI = [sys.executable, "-c", "import sys; from conformal_control.cli import main; sys.exit(main())"]
BASE = {"scene": "crossing", "frames": 10}
# 12 runs on one seed: each worker generates the built-in scene once
EPSILONS = [-0.3, -0.25, -0.2, -0.15, -0.1, -0.05, 0, 0.05, 0.1, 0.15, 0.2, 0.25]
GRID = {"epsilon": EPSILONS}
ARGS = [
    "sweep",
    "--scene",
    "crossing",
    "--grid",
    "epsilon=" + ",".join(map(str, EPSILONS)),
    "-j",
    "2",
    "--progress",
    "off",
    "--no-summary-plot",
]


def spec_keys(frames: int = 10) -> set[str]:
    return {c.key for c in SweepSpec(base={**BASE, "frames": frames}, grid=GRID).expand()}


KEYS = spec_keys()


def token_pids(token: str) -> list[int]:
    """Live (non-zombie) processes whose environment holds ``token``."""
    try:
        import psutil
    except ImportError:  # read /proc directly
        psutil = None
    found = []
    if psutil is not None:
        for p in psutil.process_iter():
            try:
                if p.status() != psutil.STATUS_ZOMBIE and p.environ().get(TOKEN) == token:
                    found.append(p.pid)
            except psutil.Error:
                continue
        return found
    marker = f"{TOKEN}={token}".encode()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
            if state not in ("Z", "X") and marker in (d / "environ").read_bytes().split(b"\0"):
                found.append(int(d.name))
        except OSError:
            continue
    return found


def wait_gone(token: str, timeout: float = 10.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while (left := token_pids(token)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def kill_token(token: str) -> None:
    """Clean-up: end the processes this test started (they carry its token), if any."""
    for pid in token_pids(token):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def start(out: Path, token: str, log: Path, *extra: str) -> subprocess.Popen:
    env = {**os.environ, TOKEN: token}
    with log.open("w") as fh:  # a file, not a pipe: orphans holding a pipe would block us
        return subprocess.Popen(
            [*CLI, *ARGS, "--set", "frames=10", *extra, "--out", str(out)],
            env=env,
            stdout=fh,
            stderr=subprocess.STDOUT,
        )


def journal(out: Path) -> list[dict]:
    path = out / "results.jsonl"
    if not path.exists():
        return []
    data = path.read_bytes()
    assert not data or data.endswith(b"\n"), "a journal line was torn"
    return [json.loads(line) for line in data.splitlines() if line.strip()]


def n_lines(out: Path) -> int:
    path = out / "results.jsonl"
    return path.read_bytes().count(b"\n") if path.exists() else 0


def table(out: Path) -> list[dict[str, str]]:
    if not (out / "results.csv").exists():
        return []
    with (out / "results.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


def check_consistent(out: Path, keys: set[str] = KEYS) -> None:
    """Nothing duplicated, nothing claimed that is not on disk, tables never ahead."""
    recs = journal(out)
    assert {r["key"] for r in recs} <= keys
    ok = Counter(r["key"] for r in recs if r["status"] == "ok")
    assert all(n == 1 for n in ok.values()), f"a finished run ran again: {ok}"
    assert not [r for r in recs if r["status"] != "ok"], "a run failed"
    for r in recs:
        assert (out / r["run_dir"] / "metrics.json").exists()
    keys = [r["key"] for r in table(out)]
    assert len(keys) == len(set(keys)) and set(keys) <= set(ok)


def check_complete(out: Path, keys: set[str] = KEYS) -> None:
    check_consistent(out, keys)
    rows = table(out)
    assert len(rows) == len({r["key"] for r in rows}) == len(keys) == 12
    assert {r["key"] for r in rows} == keys and {r["status"] for r in rows} == {"ok"}
    assert len(journal(out)) == 12


def test_random_kills_lose_and_duplicate_nothing(tmp_path: Path) -> None:
    """SIGKILL at 20 random points of a 12-run sweep (and SIGTERM once), resumed each time.

    About two in three kills land in the first 1.5 s (imports, validation, locking, reading
    the journal, starting the pool), the others at a random moment just after one or two
    more runs were recorded (while runs are in flight and the driver journals and rewrites
    its tables).
    """
    rng = random.Random(20251123)
    token = uuid.uuid4().hex
    kills, terms, rounds, folders = 0, [], 0, 0
    out = tmp_path / f"sweep{folders}"
    try:
        while kills < 20:
            rounds += 1
            before = n_lines(out)
            # once, mid-sweep: SIGTERM, which must stop the sweep cleanly (exit 143)
            sig = signal.SIGTERM if (rounds >= 5 and not terms and before <= 6) else signal.SIGKILL
            p = start(out, token, tmp_path / f"round{rounds}.log")
            if sig == signal.SIGKILL and rng.random() < 0.65:  # during start-up
                deadline = time.monotonic() + rng.uniform(0.0, 1.5)
                while p.poll() is None and time.monotonic() < deadline:
                    time.sleep(0.01)
            else:  # after one or two more runs were recorded, at a random moment
                target = before + rng.randint(1, 2)
                deadline = time.monotonic() + 60
                while p.poll() is None and n_lines(out) < target:
                    assert time.monotonic() < deadline, "the sweep made no progress"
                    time.sleep(0.005)
                time.sleep(rng.uniform(0.0, 0.2))
            sent = p.poll() is None
            if sent:
                p.send_signal(sig)
            rc = p.wait(timeout=30)
            log = (tmp_path / f"round{rounds}.log").read_text()
            left = wait_gone(token)
            assert not left, f"round {rounds}: processes left behind after {sig.name}: {left}"
            check_consistent(out)
            if sent and sig == signal.SIGKILL and rc == -signal.SIGKILL:
                kills += 1
            elif sent and sig == signal.SIGTERM and rc != 0:
                assert rc == 128 + signal.SIGTERM, log  # our handler ran: a clean stop
                assert "interrupted by SIGTERM" in log
                terms.append(rc)
            else:
                assert rc == 0, log
            if rc == 0:  # this driver finished the sweep: check it, start a fresh one
                check_complete(out)
                folders += 1
                out = tmp_path / f"sweep{folders}"
        p = start(out, token, tmp_path / "final.log")
        assert p.wait(timeout=120) == 0, (tmp_path / "final.log").read_text()
        assert not wait_gone(token)
        check_complete(out)
    finally:
        kill_token(token)
    assert kills >= 20 and terms == [128 + signal.SIGTERM]


def test_two_sweeps_on_one_folder(tmp_path: Path, capsys) -> None:
    """The second sweep stops at once, naming the first one's PID; the first finishes."""
    token = uuid.uuid4().hex
    out = tmp_path / "sw"
    try:
        # the first sweep runs in its own process (serial: no pool to start, so it is cheap)
        a = start(out, token, tmp_path / "a.log", "--set", "frames=40", "--executor", "serial")
        deadline = time.monotonic() + 60
        while True:  # until the first sweep holds the lock
            assert a.poll() is None and time.monotonic() < deadline
            try:
                if json.loads((out / ".lock").read_text())["pid"] == a.pid:
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.01)
        argv = [*ARGS, "--set", "frames=40", "--out", str(out)]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert a.poll() is None, "the first sweep ended before the second one tried"
        assert err.count("\n") == 0 and f"another sweep (PID {a.pid} " in err
        assert a.wait(timeout=120) == 0, (tmp_path / "a.log").read_text()
    finally:
        kill_token(token)
    check_complete(out, spec_keys(40))
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]
    # once the first is done, the folder is free again
    assert main([*argv, "--executor", "serial"]) == 0
    assert "12 already done, 0 ran" in capsys.readouterr().out


def test_process_pool_workers_exit_with_their_driver() -> None:
    """A worker's watchdog ends it when the driver is SIGKILLed in the middle of a task."""
    token = uuid.uuid4().hex
    code = (
        "import time\n"
        "from conformal_control.experiments import ProcessExecutor\n"
        "ex = ProcessExecutor(workers=2)\n"
        "for _ in ex.run(time.sleep, [(0.01,), (0.01,), (600,), (600,)]):\n"
        "    print('done', flush=True)\n"
    )
    env = {**os.environ, TOKEN: token}
    driver = subprocess.Popen(
        [sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        assert driver.stdout.readline().strip() == "done"
        workers = [pid for pid in token_pids(token) if pid != driver.pid]
        assert len(workers) >= 2  # fork server + pool workers (+ resource tracker)
        driver.kill()
        driver.wait()
        assert not wait_gone(token), "pool workers outlived a SIGKILLed driver"
    finally:
        driver.stdout.close()
        kill_token(token)


def test_ctrl_c_on_the_batch_executor_journals_every_finished_run(tmp_path: Path) -> None:
    """Ctrl-C (SIGINT to the whole process group) during ``sweep --executor batch``: every
    run whose directory is complete is in the journal, and the message says what is."""
    out = tmp_path / "sw"
    token = uuid.uuid4().hex
    eps = ",".join(f"{-0.45 + 0.9 * i / 300:.4f}" for i in range(300))
    argv = [*CLI, "sweep", "--scene", "crossing", "--grid", f"epsilon={eps}", "--set"]
    argv += ["frames=10", "--executor", "batch", "-j", "2", "--progress", "off"]
    argv += ["--no-summary-plot", "--out", str(out)]
    log = tmp_path / "log.txt"
    with log.open("w") as fh:
        proc = subprocess.Popen(
            argv,
            env={**os.environ, TOKEN: token},
            stdout=fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        deadline = time.monotonic() + 240
        while len(list(out.glob("runs/*/metrics.json"))) < 20 and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
        rc = proc.wait(timeout=120)
        assert wait_gone(token) == []
    finally:
        kill_token(token)
    text = log.read_text()
    assert rc == 128 + signal.SIGINT, text
    recs = journal(out)
    in_journal = {r["key"] for r in recs if r["status"] == "ok"}
    finished = set()
    for metrics in out.glob("runs/*/metrics.json"):
        cfg = json.loads((metrics.parent / "config.json").read_text())
        finished.add(cfg["sweep"]["key"])
    assert finished and finished <= in_journal, f"{len(finished - in_journal)} not journaled"
    assert len(in_journal) < 300  # it was stopped
    assert f"{len(in_journal)} finished and 0 failed run(s) are in the journal" in text, text
    check_consistent(
        out,
        {
            c.key
            for c in SweepSpec(
                base={"scene": "crossing", "frames": 10},
                grid={"epsilon": [float(v) for v in eps.split(",")]},
            ).expand()
        },
    )


def test_sigterm_to_bench_run_says_what_is_kept_and_exits_143(
    tmp_path: Path, data_root: Path
) -> None:
    """``bench run`` stopped by SIGTERM: exit 128 + 15, and its one line says how many
    episodes its journal holds and how to resume (it said only ``interrupted``, exit 130)."""
    out = tmp_path / "bench"
    token = uuid.uuid4().hex
    argv = [*CLI, "bench", "run", "--split", "dev", "--methods", "nolearn,conformal"]
    argv += ["--limit", "40", "--executor", "serial", "--progress", "off"]
    argv += ["--data-root", str(data_root), "--out", str(out)]
    log = tmp_path / "log.txt"
    with log.open("w") as fh:
        proc = subprocess.Popen(
            argv, env={**os.environ, TOKEN: token}, stdout=fh, stderr=subprocess.STDOUT
        )
    try:
        deadline = time.monotonic() + 240
        while n_lines(out) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=60)
        assert wait_gone(token) == []
    finally:
        kill_token(token)
    text = log.read_text()
    assert rc == 128 + signal.SIGTERM, text
    ok = sum(r["status"] == "ok" for r in journal(out))
    assert 2 <= ok < 80, text
    assert f"error: interrupted by SIGTERM: {ok} finished and 0 failed run(s)" in text, text
    assert "run the same command again to resume" in text
