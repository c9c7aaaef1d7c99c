"""A sweep run is a RunSpec on a named scene (:class:`SweepRun`), and its key is the key 0.3
gave the same run: results folders written by 0.3 resume without a run done again.

The pinned keys below were computed by 0.3's ``RunConfig`` (main at 56d88d7, before
``SweepRun``), by running the same calls as the tests below on that commit.
``sweep_0_3/`` is a results folder that code wrote (a six-run sweep of the built-in
crossing, ``plot="metrics"``; kept: the journal, ``sweep.json`` and each run's
``metrics.json``, which is what a resumed sweep reads; the worker field anonymised).
"""

from __future__ import annotations

import csv
import hashlib
import shutil
from pathlib import Path

import pytest

from conformal_control.core.exceptions import ConformalControlDeprecationWarning
from conformal_control.core.spec import RunSpec
from conformal_control.experiments import SweepRun, SweepSpec, run_sweep
from conformal_control.experiments.bench.methods import expand_methods
from conformal_control.experiments.bench.suite import bench_configs
from conformal_control.experiments.plan import RunConfig, settings_view
from conformal_control.experiments.reproduce.report import plan

FOLDER_0_3 = Path(__file__).parent / "sweep_0_3"

#: A sweep whose runs write settings at their default (``rule: fixed_eta``), leave them
#: out, nest them (``family_params.alpha``), set options (``lambda_safe: auto`` fills in
#: its source) and roles (``fallback``).
SWEEP = {
    "base": {"scene": "crossing", "frames": 30, "label": "x", "data_root": "/nowhere"},
    "grid": {"epsilon": [-0.1, 0.0, 0.25], "seed": [0, 1]},
    "runs": [
        {},
        {"learn": False},
        {"family": "acp", "family_params.alpha": 0.1},
        {"rule": "fixed_eta", "rule_params": {}},
        {"rule": "fixed_eta"},
        {"predictor": "oracle", "crowd": "social_force", "record_animation": False},
        {"lambda_safe": "auto", "units": "si", "eta": 2.0},
        {"predictor_params.window": 3, "tau": 4.0, "crowd": "replay"},
        {"engine": "loop", "fallback": "brake", "lambda_init": -1},
    ],
}
#: 0.3's keys of SWEEP's 54 runs, in order.
KEYS_0_3 = [
    "0def5868e62e676a",
    "739d9daceaae8fdc",
    "5f6fdd4d623303b8",
    "1cb998fd2eb148ba",
    "360f92645b45c565",
    "0c2f991d086c8247",
    "b5fbc57b309ddcf2",
    "6acc7cfef506a4eb",
    "0ff19209cab74de7",
    "be52aad4385059e9",
    "9fec2662267da4b8",
    "91490bc5c602e240",
    "57ca7f2d561f1096",
    "b0742382d8d9d5d7",
    "8aaf0b81883ca036",
    "875b2d62c789eed4",
    "85d561d9cfaf164a",
    "557b402e9c3e583f",
    "e9e9571adb0d6c7f",
    "3223864c26188435",
    "d3be4b0f7fefd7bb",
    "66dc7386cf506c97",
    "38734fc2d4707cb0",
    "893d644ca7e12360",
    "6fa55a079b1d76a7",
    "6e527d5f75be21d4",
    "4c88aa22620cd68a",
    "152c34b8363a3775",
    "a43ed86e27b26f37",
    "bd897710067669ef",
    "4bf9c6982ec9a335",
    "4306b4178d0dfe1e",
    "0d4a7ecd6ce7263b",
    "c221b06a3dcdeaf3",
    "f7a3003d62f258d2",
    "91c41037a9d4d8f8",
    "08fe81bdc7eb39c4",
    "f602aae44a4f0e2a",
    "410b72a0b63a8a3b",
    "a82572eddcc30eb1",
    "29f96eb0e8a78e08",
    "a35ff7ac9c60fdbf",
    "1a48996e0ec57b71",
    "a4aee9cb07e97c9b",
    "ebb5d1390e7c9780",
    "8ff02fdb4105d914",
    "3e6d9a98e790e013",
    "cf8bdf5d4ee326b4",
    "5dd1a036213c4b25",
    "169b2fc9a271faa8",
    "1d1da91bee30673b",
    "4e1846e45efba2cb",
    "906f5bfe34fa9f3a",
    "bf52b38c9bdc0615",
]


#: The benchmark's families at 56d88d7.
FAMILIES_0_3 = [
    "acp", "acp_mpc", "cc_mpc", "cc_mpc_margin", "conformal", "conformal_aci",
    "conformal_agent", "conformal_agent_dtaci", "conformal_dtaci", "conformal_dtaci_floor",
    "conformal_pid", "ecp_mpc", "fallback:brake", "fallback:relax", "fcp_mpc", "fixed",
    "inflated", "mpc", "nolearn", "oracle", "oracle_mpc",
]  # fmt: skip


def _digest(keys: list[str]) -> str:
    return hashlib.sha256(",".join(keys).encode()).hexdigest()[:16]


def test_a_sweep_keeps_the_keys_of_0_3() -> None:
    assert [r.key for r in SweepSpec.from_mapping(SWEEP).expand()] == KEYS_0_3


@pytest.mark.parametrize(
    ("shifts", "crowd", "n", "digest", "first"),
    [
        (
            ("nominal", "delay-0.5s", "learned"),
            "replay",
            168,
            "b489276f05df30d0",
            ["5a9f696a13ab5117", "03c556173bd79226", "961777506d48af7b"],
        ),
        (
            ("nominal",),
            "social_force",
            56,
            "5833e6734d953326",
            ["1a6adf8fa875615a", "3a0f7922666ac415", "129ff97c4a62cc29"],
        ),
    ],
)
def test_the_benchmark_keeps_the_keys_of_0_3(shifts, crowd, n, digest, first) -> None:
    # every family of 56d88d7, two test scenarios: the benchmark writes rule, rule_params
    # and units out even at their default, and 0.3 hashed them (a family whose settings
    # change later changes its runs, and so its keys: pin them again then)
    methods = expand_methods(FAMILIES_0_3)
    runs = bench_configs("crossings-v2", "test", methods, limit=2, shifts=shifts, crowd=crowd)
    keys = [r.key for r in runs]
    assert (len(keys), _digest(keys), keys[:3]) == (n, digest, first)


def test_the_paper_tables_keep_the_keys_of_0_3() -> None:
    keys = [r.key for r in plan(["table1", "table2", "forms"], frames=200)]
    assert (len(keys), _digest(keys), keys[:3]) == (
        42,
        "428a8354c7987245",
        ["9b7a2ee5e98242b5", "701836602654a98d", "aed379c430c11747"],
    )


def _csv(path: Path) -> list[dict[str, str]]:
    with (path / "results.csv").open() as fh:
        return list(csv.DictReader(fh))


def test_a_folder_written_by_0_3_resumes_with_no_run_redone(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    shutil.copytree(FOLDER_0_3, out)
    runs = [
        {},
        {"rule": "fixed_eta", "rule_params": {}, "label": "explicit"},
        {"family": "acp", "learn": False},
    ]
    spec = {"base": {"scene": "crossing", "frames": 5}, "grid": {"epsilon": [-0.1, 0.1]}}
    kw = dict(executor="serial", plot="none", summary_plot=False, progress=False, parquet=False)
    again = run_sweep(SweepSpec.from_mapping({**spec, "runs": runs}), out, **kw)
    assert again.ran == [] and len(again.skipped) == 6
    # one more epsilon: three new runs, journaled by this version beside 0.3's records,
    # and the table has the same columns for both
    spec["grid"]["epsilon"].append(0.0)
    more = run_sweep(SweepSpec.from_mapping({**spec, "runs": runs}), out, **kw)
    assert len(more.ran) == 3 and len(more.skipped) == 6
    rows = _csv(out)
    config = [c for c in rows[0] if c.split(".")[0] in ("episode", "param", "predictor_params")]
    config += ["label", "scene", "predictor", "learn", "seed", "max_frames"]
    new = {r["key"]: r for r in rows if r["key"] in more.ran}
    old = [r for r in rows if r["key"] not in more.ran]
    for n in new.values():
        twin = next(o for o in old if o["label"] == n["label"] and o["learn"] == n["learn"])
        assert {c: n[c] for c in config if c != "param.epsilon"} == {
            c: twin[c] for c in config if c != "param.epsilon"
        }
    assert {r["episode.rule"] for r in new.values()} == {"", "fixed_eta"}


def test_the_journal_stores_the_run_specification_as_it_is() -> None:
    run = SweepRun.from_flat({"scene": "crossing", "epsilon": -0.1, "family": "acp", "frames": 9})
    stored = run.as_dict()
    assert stored["spec"] == run.spec.as_dict() and stored["given"] == ["family"]
    back = SweepRun.from_dict(stored)
    assert back == run and back.key == run.key
    # a 0.3 record reads back as the same run, and its view is the record itself
    flat = settings_view(stored)
    assert settings_view(flat) == flat
    assert SweepRun.from_dict(flat).key == run.key
    assert flat["episode"] == {"family": "acp"} and flat["frames"] == 9


def test_a_setting_at_its_default_enters_the_key_only_when_written() -> None:
    plain = SweepRun.from_settings("crossing", {"epsilon": 0.1})
    written = SweepRun.from_settings("crossing", {"epsilon": 0.1}, rule="fixed_eta")
    assert plain.spec == written.spec and plain.key != written.key
    # a changed setting needs no writing out: the spec carries it
    acp = SweepRun("crossing", RunSpec(params={"epsilon": 0.1}, family="acp"))
    assert acp.key == SweepRun.from_settings("crossing", {"epsilon": 0.1}, family="acp").key


def test_run_config_is_a_deprecated_name_of_the_same_run() -> None:
    with pytest.warns(ConformalControlDeprecationWarning, match="not before 2027-06-30"):
        old = RunConfig(
            scene="crossing", frames=5, params={"epsilon": 0.1}, episode={"family": "acp"}
        )
    new = SweepRun.from_settings("crossing", {"epsilon": 0.1}, max_frames=5, family="acp")
    assert old == new
