"""The scripts that read a family_eval.py working folder (benchmarks/workdir.py): which families
they read, and a folder or family without data is one line naming it and what makes it, exit
status 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
import typer
from helpers import BENCHMARKS, load_benchmark


@pytest.fixture(scope="module")
def workdir():
    return load_benchmark("workdir")


def make_family(out, family, methods=()):
    (out / family).mkdir(parents=True)
    (out / family / "sensor.yaml").write_text("{}\n")
    for method in methods:
        (out / "predictions" / family / method).mkdir(parents=True)


def test_without_names_every_family_with_data_is_read_in_order(workdir, tmp_path):
    make_family(tmp_path, "strong", ["ours"])
    make_family(tmp_path, "default", ["ours", "paper"])
    make_family(tmp_path, "late", ["paper"])
    (tmp_path / "notes").mkdir()  # a folder without a dataset is not a family
    assert workdir.families_in(tmp_path) == ["default", "late", "strong"]
    assert workdir.families_in(tmp_path, method="ours") == ["default", "strong"]
    assert workdir.families_in(tmp_path, " late , default", method="paper") == ["late", "default"]


@pytest.mark.parametrize(
    ("names", "method", "said"),
    [
        ("fingers", None, "fingers: no dataset"),
        ("default", "paper", "no predictions of method 'paper'"),
        ("", "paper", "no family datasets with predictions of method 'paper'"),
    ],
)
def test_a_family_without_data_is_a_usage_error(workdir, tmp_path, capsys, names, method, said):
    make_family(tmp_path, "default", ["ours"])
    with pytest.raises(typer.Exit) as stop:
        workdir.families_in(tmp_path, names, method)
    assert stop.value.exit_code == 2
    err = capsys.readouterr().err
    assert said in err and "family_eval.py --out" in err


@pytest.mark.parametrize(
    ("script", "args"),
    [
        ("resting_errors.py", ["--method", "ours"]),
        ("felt_errors.py", ["--families", "late"]),
        ("onset_bound.py", []),
        ("wait_bound.py", ["--seed", "2"]),
        ("../docs/lab/contact_count.py", ["--families", "default"]),
        ("../docs/lab/type_commitment.py", ["--families", "default"]),
        ("../docs/lab/gesture_collar.py", ["--families", "strong"]),
        ("../docs/lab/count_collar.py", ["--method", "ours"]),
        ("../docs/lab/creep_misfit.py", []),
        ("profile_felt.py", ["--method", "ours"]),
        ("felt_pooled.py", ["--method", "ours"]),
    ],
)
def test_each_script_refuses_a_folder_without_data_in_one_unwrapped_line(tmp_path, script, args):
    out = tmp_path / ("a folder whose name is long enough to pass eighty columns" * 2)
    out.mkdir()
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), "--out", str(out), *args], capture_output=True, text=True
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(out) in lines[0], done.stderr
    assert done.stdout == ""


def test_numbers_are_read_or_refused_naming_the_option(workdir, capsys):
    assert workdir.numbers("0.1, 2,inf", "--mm") == [0.1, 2.0, float("inf")]
    for text, finite in (("1,x", False), ("-1", False), ("nan", False), ("inf", True), ("", False)):
        with pytest.raises(typer.Exit) as stop:
            workdir.numbers(text, "--mm", finite=finite)
        assert stop.value.exit_code == 2 and "--mm: expected comma-separated" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("script", "args"),
    [
        ("wait_bound.py", ["--seed", "2", "--families", "default", "--wait-ms", "90,inf"]),
        ("onset_bound.py", ["--mm", "0.1,x"]),
        ("resting_errors.py", ["--method", "ours", "--ideal-mm", "-0.1"]),
        ("resting_errors.py", ["--method", "ours", "--collar-ms", "40,inf"]),
        ("../docs/lab/type_commitment.py", ["--families", "default", "--first-finger-ms", "90,nan"]),
    ],
)
def test_each_script_refuses_a_bad_number_in_one_line(tmp_path, script, args):
    make_family(tmp_path, "default", ["ours"])
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), "--out", str(tmp_path), *args], capture_output=True, text=True
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "expected comma-separated" in lines[0], done.stderr


@pytest.mark.parametrize(
    ("script", "args"),
    [
        ("family_eval.py", ["--users", "0,x"]),
        ("family_eval.py", ["--users", "12"]),
        ("adapt_eval.py", ["--users", "3,"]),
        ("tune_pipeline.py", ["--chamfer", "0.002,nan"]),
    ],
)
def test_a_bad_user_or_threshold_is_a_usage_error_before_any_work(tmp_path, script, args):
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / script), "--out", str(out), *args], capture_output=True, text=True
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and "expected comma-separated" in done.stderr
    assert not out.exists()  # nothing simulated or written
