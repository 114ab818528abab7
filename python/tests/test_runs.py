"""Runs and benches from Python: the summary of `optalign run --sim` and rows of
`optalign bench`."""

import pytest

import optalign


def test_a_run_returns_its_summary():
    summary = optalign.run("cavity", policy="vision", seed=0)
    assert summary["task"] == "cavity" and summary["policy"] == "vision"
    assert summary["success"] is True
    assert 1 <= summary["evaluations_used"] <= summary["budget"] == 50
    assert len(summary["error_trace"]) == summary["evaluations_used"] + 1
    assert summary["terminal_error"] == summary["error_trace"][-1]


def test_a_run_can_write_its_transcript(tmp_path):
    out = tmp_path / "run"
    summary = optalign.run("michelson", policy="random", seed=1, out=out)
    assert summary["evaluations_used"] == 60
    assert (out / "transcript.jsonl").exists()


def test_bench_rows_match_single_runs_and_suit_a_data_frame():
    rows = optalign.bench(["cavity"], ["random", "bo"], [0, 1], jobs=2)
    assert [(r["policy"], r["seed"]) for r in rows] == [
        ("random", 0),
        ("random", 1),
        ("bo", 0),
        ("bo", 1),
    ]
    columns = list(rows[0])
    assert all(list(row) == columns for row in rows)
    assert columns[:4] == ["task", "policy", "seed", "success"], "results.csv's order"
    assert {"terminal_error", "evaluations_used", "milestone_m1", "failure"} <= set(columns)
    single = optalign.run("cavity", policy="random", seed=1)
    assert rows[1]["terminal_error"] == single["terminal_error"]


def test_bad_names_are_refused_clearly():
    with pytest.raises(ValueError, match='unknown task "laser"'):
        optalign.run("laser")
    with pytest.raises(ValueError, match="at least one task"):
        optalign.bench([], ["random"], [0])
    with pytest.raises(TypeError, match="lists of names"):
        optalign.bench("cavity", ["random"], [0])
    with pytest.raises(ValueError, match='unknown policy "oracle": use vision, bo, random'):
        optalign.run("cavity", policy="oracle")
    with pytest.raises(ValueError, match="optalign run --policy vlm"):
        optalign.bench(["cavity"], ["vlm"], [0])
