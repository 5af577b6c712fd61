"""What goes to a pipe or a file is exact: a profile's bytes, tables at their full width.

rich writes 80 columns to anything that is not a terminal; these run the command as a user does,
with stdout a pipe (a subprocess), or a file (``> mine.yaml``).
"""

from __future__ import annotations

from helpers import run_cli

from neurotouch_hid.mapping.profile import load_profile, shipped_profiles_dir


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
