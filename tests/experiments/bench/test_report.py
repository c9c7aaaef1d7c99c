"""Reports are built from stored rows: leaderboard, paired comparison, Pareto front."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from conformal_control.experiments.bench.report import _pareto, summarise, with_tuned, write_report


def rows() -> list[dict]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(40):
        base_coll = int(rng.integers(0, 6))
        for method, coll, t in (("nolearn", base_coll, 10.0), ("conformal[eps=-0.1]", 0, 12.0)):
            reached = not (method == "conformal[eps=-0.1]" and i == 0)
            out.append(
                {
                    "scenario": f"s{i}",
                    "source": f"video{i % 3}",
                    "method": method,
                    "family": method.split("[")[0],
                    "setting": "eps=-0.1" if "eps" in method else "",
                    "status": "ok",
                    "success": str(reached and coll == 0).lower(),
                    "goal_reached": str(reached).lower(),
                    "any_collision": str(coll > 0).lower(),
                    "n_collide": coll,
                    "t_goal": t if reached else "",
                    "time_limit": 30.0,
                    "d_min": 1.0,
                }
            )
    out.append({"scenario": "s99", "method": "nolearn", "status": "failed"})
    return out


def test_summaries_and_paired_comparison() -> None:
    data = rows()
    by = {s.method: s for s in summarise(data)}
    base, conf = by["nolearn"], by["conformal[eps=-0.1]"]
    assert base.n == 40 and base.n_failed == 1 and conf.n == 40
    base_coll = np.array(
        [r["n_collide"] for r in data if r.get("method") == "nolearn" and "n_collide" in r]
    )
    assert base.estimates["collision frames"].mean == pytest.approx(base_coll.mean())
    pc = conf.paired["collision frames"]
    assert pc.n == 40 and pc.wins == int((base_coll > 0).sum()) and pc.losses == 0
    assert pc.difference.high < 0
    # the episode that did not reach its goal counts at its time limit in the frontier column
    t = conf.estimates["time to goal (s, limit if not reached)"].mean
    assert t == pytest.approx((39 * 12.0 + 30.0) / 40)
    assert conf.estimates["time to goal (s, reached)"].n == 39


def test_pareto_front() -> None:
    assert _pareto([(1.0, 1.0), (2.0, 0.5), (2.0, 2.0), (0.5, 3.0)]) == [True, True, False, True]


def test_write_report_files(tmp_path) -> None:
    files = write_report(rows(), tmp_path, title="toy")
    md = files["leaderboard.md"].read_text()
    assert "| `nolearn` | 40 (1 failed) |" in md and "Paired with `nolearn`" in md
    with files["leaderboard.csv"].open() as fh:
        table = list(csv.DictReader(fh))
    assert [r["method"] for r in table] == ["nolearn", "conformal[eps=-0.1]"]
    assert files["frontier.png"].stat().st_size > 10_000
    assert (tmp_path / "success_vs_epsilon.png").exists()
    with pytest.raises(ValueError, match="no successful episode"):
        write_report([{"method": "x", "status": "failed"}], tmp_path / "empty")


def test_a_report_is_a_function_of_the_set_of_rows(tmp_path) -> None:
    """Shuffling the rows (as a process pool stores them, in the order episodes finish)
    used to change the intervals and the order of methods in every table."""
    data = rows()
    data += [  # a third method, so the order of methods can matter
        {**r, "method": "acp[alpha=0.1]", "family": "acp", "setting": "x", "n_collide": 1}
        for r in data
        if r.get("method") == "nolearn" and "n_collide" in r
    ]
    first = write_report(data, tmp_path / "a", title="toy")
    rng = np.random.default_rng(7)
    shuffled = [data[i] for i in rng.permutation(len(data))]
    second = write_report(shuffled, tmp_path / "b", title="toy")
    for name, path in first.items():
        if path.suffix in (".md", ".csv"):
            assert path.read_bytes() == second[name].read_bytes(), name
    assert [s.method for s in summarise(data)] == [s.method for s in summarise(shuffled)]


def test_canonical_order_is_the_sort_by_every_key() -> None:
    """The order sorts by shift, method and scenario and serialises only rows that tie on
    them: it must equal sorting every row by all four keys."""
    import json

    from conformal_control.experiments.bench.report import canonical_order

    data = rows()
    data += [{**r, "n_collide": 7, "shift": "delay-0.5s"} for r in data[:6]]
    data += [{**r, "wall_s": 0.5} for r in data[:4]] + [dict(data[1])]  # ties, a duplicate
    rng = np.random.default_rng(2)
    shuffled = [data[i] for i in rng.permutation(len(data))]

    def full(r):
        return (str(r.get("shift") or "nominal"), str(r.get("method")), str(r.get("scenario")),
                json.dumps(r, sort_keys=True, default=str))  # fmt: skip

    assert canonical_order(shuffled) == sorted(shuffled, key=full)


@pytest.mark.parametrize("split", ["dev", "test"])
def test_the_tuned_label_comes_from_the_tuned_file(tmp_path, split) -> None:
    """The report printed "(tuned on dev)" whatever split the values were tuned on."""
    bench = {"tuned": {"split": split, "values": {"conformal": -0.1}}}
    files = write_report(rows(), tmp_path, title="toy", bench=bench)
    md = files["leaderboard.md"].read_text()
    assert f"| `conformal[eps=-0.1]` (tuned on {split}) |" in md
    other = "test" if split == "dev" else "dev"
    assert f"tuned on {other}" not in md
    with files["leaderboard.csv"].open() as fh:
        roles = {r["method"]: r["role"] for r in csv.DictReader(fh)}
    assert roles["conformal[eps=-0.1]"] == f"tuned on {split}"


def test_report_tuned_from_another_file_labels_a_family_added_later(tmp_path) -> None:
    """``bench report --tuned FILE``: rows run before ``conformal`` was in the run's tuned
    file are labelled tuned by the values of FILE; a tuned member without rows is named."""
    import json

    bench = {"suite": "crossings-v2", "tuned": {"split": "dev", "values": {}, "source": "old"}}
    md = write_report(rows(), tmp_path / "a", bench=bench)["leaderboard.md"].read_text()
    assert "(tuned on dev)" not in md  # the run's file did not list conformal
    tuned = tmp_path / "tuned.json"
    doc = {"suite": "crossings-v2", "split": "dev", "families": {"conformal": {"setting": -0.1}}}
    tuned.write_text(json.dumps(doc))
    new, missing = with_tuned(bench, tuned, rows())
    assert new["tuned"]["values"] == {"conformal": -0.1} and new["tuned"]["replaced"] == "old"
    assert missing == []
    md = write_report(rows(), tmp_path / "b", bench=new)["leaderboard.md"].read_text()
    assert "| `conformal[eps=-0.1]` (tuned on dev) |" in md
    doc["families"]["conformal"]["setting"] = -0.3  # a member the folder never ran
    tuned.write_text(json.dumps(doc))
    assert with_tuned(bench, tuned, rows())[1] == [("conformal", "conformal[eps=-0.3]")]
    with pytest.raises(ValueError, match="tuned on suite"):
        with_tuned({**bench, "suite": "fcp-planar"}, tuned, rows())
    with pytest.raises(ValueError, match="does not name its suite"):
        with_tuned({}, tuned, rows())
