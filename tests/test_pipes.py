"""What goes to a pipe or a file is exact: a profile's bytes, tables at their full width.

rich writes 80 columns to anything that is not a terminal; these run the command as a user does,
with stdout a pipe (a subprocess), or a file (``> mine.yaml``).
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import BENCHMARKS, load_benchmark, run_cli

from neurotouch_hid.mapping.profile import load_profile, shipped_profiles_dir
from neurotouch_hid.sources.physics import PHYSICS


def test_profile_show_piped_is_the_file(tmp_path):
    for shipped in sorted(shipped_profiles_dir().glob("*.yaml")):
        result = run_cli("profile", "show", shipped.stem, home=tmp_path, text=False)
        assert result.returncode == 0, result.stderr
        assert result.stdout == shipped.read_bytes(), shipped.stem


def test_profile_show_to_a_file_validates(tmp_path):
    mine = tmp_path / "mine.yaml"
    with open(mine, "wb") as fh:
        assert run_cli("profile", "show", "default", home=tmp_path, text=False, stdout=fh).returncode == 0
    assert mine.read_bytes() == (shipped_profiles_dir() / "default.yaml").read_bytes()
    checked = run_cli("profile", "validate", str(mine), home=tmp_path, text=False)
    assert checked.returncode == 0, checked.stderr
    assert b": ok (" in checked.stdout


def test_wide_table_to_a_pipe_is_not_cropped(tmp_path):
    """`profile list`'s rows are wider than 80 columns (the default profile's description alone is
    over 100): piped, each row keeps its whole description and status on one line."""
    result = run_cli("profile", "list", home=tmp_path, text=False)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.decode().splitlines()
    description = load_profile(shipped_profiles_dir() / "default.yaml").description
    assert len(description) > 80
    row = [line for line in lines if description in line]
    assert len(row) == 1 and "ok" in row[0].split(description)[1], result.stdout.decode()


#: The benchmarks' typer scripts (each builds its app with ``command_app``).
TYPER_BENCHMARKS = sorted(p.stem for p in BENCHMARKS.glob("*.py") if "command_app()" in p.read_text())
#: Those with a required option or argument (``typer.Option(...`` / ``typer.Argument(...``): the
#: others run on their defaults without one.
REQUIRING_BENCHMARKS = [s for s in TYPER_BENCHMARKS if "(...," in (BENCHMARKS / f"{s}.py").read_text()]


def test_every_typer_benchmark_is_covered():
    typer_scripts = sorted(p.stem for p in BENCHMARKS.glob("*.py") if "import typer" in p.read_text())
    assert TYPER_BENCHMARKS == [s for s in typer_scripts if s != "workdir"]


@pytest.mark.parametrize("script", REQUIRING_BENCHMARKS)
def test_benchmark_usage_error_to_a_pipe_is_one_plain_line(script):
    """Without its required option or command, a benchmark says so on one unboxed line (rich's
    boxes, cropped at 80 columns, were what a CI log got)."""
    result = subprocess.run(
        [sys.executable, str(BENCHMARKS / f"{script}.py")], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error: Missing ")]
    assert len(errors) == 1, result.stderr
    assert not set("╭│╰…") & set(result.stderr), result.stderr


@pytest.mark.parametrize("script", sorted(set(TYPER_BENCHMARKS) - set(REQUIRING_BENCHMARKS)))
def test_a_benchmark_on_defaults_refuses_an_unknown_option_in_one_plain_line(script):
    result = subprocess.run(
        [sys.executable, str(BENCHMARKS / f"{script}.py"), "--no-such-option"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error: No such option")]
    assert len(errors) == 1, result.stderr
    assert not set("╭│╰…") & set(result.stderr), result.stderr


def test_benchmark_help_to_a_pipe_is_not_cropped():
    """``family_eval.py --help`` piped: the default family list (over 100 characters) is whole,
    on the line of its option."""
    result = subprocess.run(
        [sys.executable, str(BENCHMARKS / "family_eval.py"), "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    families = ",".join(f for f in PHYSICS if f not in load_benchmark("family_eval").HELD_BACK)
    assert len(families) > 100
    (line,) = [line for line in result.stdout.splitlines() if line.lstrip().startswith("--families")]
    assert f"[default: {families}]" in line, result.stdout
    assert "…" not in result.stdout


def test_every_scripts_help_to_a_pipe_is_whole():
    """Every script of benchmarks/ and docs/lab/ with options builds its command with
    ``command_app`` (click's plain help, never cut in a pipe), and ``gesture_collar.py --help``
    piped shows its default family list whole (rich's boxes had cropped it at 80 columns)."""
    scripts = sorted(BENCHMARKS.glob("*.py")) + sorted((BENCHMARKS.parent / "docs" / "lab").glob("*.py"))
    own = [p for p in scripts if "typer.Option(" in p.read_text()]
    assert len(own) > 10
    assert [p.name for p in own if "command_app" not in p.read_text()] == []
    result = subprocess.run(
        [sys.executable, str(BENCHMARKS.parent / "docs" / "lab" / "gesture_collar.py"), "--help"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    (line,) = [line for line in result.stdout.splitlines() if line.lstrip().startswith("--families")]
    assert "[default: powerlaw,drift,strong,viscoelastic,late,camera,contrast]" in line, result.stdout
    assert not set("╭│╰…") & set(result.stdout), result.stdout
