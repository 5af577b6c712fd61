"""The first hour of a new user: every message says what is true and where (the line to fix, the
file that holds the text), and every command the docs show works as written."""

from __future__ import annotations

import io
import re
import sys
import textwrap
from pathlib import Path

import pytest

from neurotouch_hid.core.errors import ProfileError
from neurotouch_hid.core.limits import YamlError, load_yaml
from neurotouch_hid.mapping.profile import load_profile, shipped_profiles_dir


# --- YAML errors at the line to fix, with the hint that fits --------------------------------------
def test_a_key_without_its_colon_is_reported_at_its_own_line_with_a_colon_hint():
    text = "a:\n  b: 1\n  c 2\n  d: 3\n"
    with pytest.raises(YamlError) as caught:
        load_yaml(text)
    assert caught.value.line == 3
    assert "no ':'" in caught.value.problem and "indentation" not in caught.value.problem


def test_an_error_at_the_end_of_the_text_is_on_its_last_line_never_past_it():
    for text in ("a:\n  b: 1\n  c 2\n", "a:\n  b: 1\n  c 2", 'a: 1\nb: "open\n'):
        with pytest.raises(YamlError) as caught:
            load_yaml(text)
        assert 1 <= caught.value.line <= len(text.splitlines()), (text, caught.value.line)
    with pytest.raises(YamlError) as caught:
        load_yaml('a: 1\nb: "open\nc: 2\n')
    assert caught.value.line == 2 and "quote" in caught.value.problem  # where the quote opens


def test_a_shipped_profile_missing_a_colon_on_its_last_key_names_that_line(tmp_path):
    lines = (shipped_profiles_dir() / "accessibility.yaml").read_text().splitlines(keepends=True)
    broken = next(i for i in range(len(lines) - 2, 0, -1) if lines[i].strip().startswith("exponent:"))
    lines[broken] = lines[broken].replace("exponent:", "exponent", 1)
    path = tmp_path / "mine.yaml"
    path.write_text("".join(lines))
    with pytest.raises(ProfileError) as caught:
        load_profile(path)
    assert f"{path}:{broken + 1}: not valid YAML" in str(caught.value)
    assert "indentation" not in str(caught.value)


def test_profile_set_on_a_broken_profile_cites_the_line_to_fix_within_the_file(cli):
    assert cli("new", "mine", "--from", "default").returncode == 0
    path = cli.user_dir / "mine.yaml"
    text = path.read_text().rstrip("\n") + "\n  extra 1\n"  # the last line lacks its colon
    path.write_text(text)
    failed = cli("set", "mine", "mappings.push.deadzone_mm", "1.0")
    assert failed.returncode == 2 and "Traceback" not in failed.stderr
    n_lines = len(text.splitlines())
    assert f"{path}:{n_lines}: not valid YAML" in failed.stderr
    assert "profile edit mine" in failed.stderr
    assert path.read_text() == text


@pytest.fixture()
def breaking_editor(tmp_path, monkeypatch):
    """$EDITOR: drops the colon after ``exponent`` on its first call, puts it back on the next."""
    calls = tmp_path / "calls"
    script = tmp_path / "editor.sh"
    script.write_text(
        textwrap.dedent(
            f"""\
            #!/bin/sh
            echo x >> {calls}
            if [ "$(wc -l < {calls})" -eq 1 ]; then
                sed -i 's/exponent: 1.5 /exponent 1.5 /' "$1"
            else
                sed -i 's/exponent 1.5 /exponent: 1.2 /' "$1"
            fi
            """
        )
    )
    script.chmod(0o755)
    monkeypatch.setenv("EDITOR", str(script))
    return calls


def test_a_rejected_edit_names_the_file_that_holds_it_and_the_next_edit_starts_from_it(
    cli, breaking_editor, monkeypatch
):
    assert cli("new", "mine", "--from", "default").returncode == 0
    path = cli.user_dir / "mine.yaml"
    before = path.read_text()
    broken_line = next(i for i, line in enumerate(before.splitlines(), 1) if "exponent: 1.5" in line)
    monkeypatch.setattr(sys, "stdin", io.StringIO("n\n"))
    given_up = cli("edit", "mine")
    rejected = cli.user_dir / "mine.yaml.rejected"
    assert given_up.returncode == 2 and path.read_text() == before
    # the lines cited are those of the file that holds the broken text, not of the kept profile
    assert f"{rejected}:{broken_line}: not valid YAML" in given_up.stderr
    assert f"{path}:{broken_line}" not in given_up.stderr
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    fixed = cli("edit", "mine")  # starts from the rejected text, which the editor now fixes
    assert fixed.returncode == 0, fixed.stderr
    assert str(rejected) in fixed.stderr
    assert "exponent: 1.2 " in path.read_text()
    assert not rejected.exists()  # nothing stale left beside the profile


# --- typos and values: the nearest name, YAML's own values, the project's words -------------------
def test_resetting_a_mistyped_shipped_name_suggests_that_name_not_deleting(cli):
    wrong = cli("reset", "defualt")
    assert wrong.returncode == 2
    assert "did you mean 'neurotouch-hid profile reset default'?" in wrong.stderr
    assert "profile delete" not in wrong.stderr  # there is no user profile 'defualt' to delete


def test_unsetting_a_mistyped_field_names_it_and_the_nearest_field(cli):
    assert cli("new", "mine", "--from", "accessibility").returncode == 0
    wrong = cli("unset", "mine", "mappings.move.deadzone_zm")
    assert wrong.returncode == 2
    assert "'deadzone_zm' is not a field" in wrong.stderr and "did you mean 'deadzone_mm'?" in wrong.stderr
    assert "is not set" not in wrong.stderr
    typo = cli("unset", "mine", "mappings.mvoe.deadzone_mm")
    assert typo.returncode == 2 and "did you mean 'move'?" in typo.stderr


def test_setting_a_mistyped_field_cites_no_line_of_a_text_that_is_in_no_file(cli):
    assert cli("new", "mine", "--from", "accessibility").returncode == 0
    path = cli.user_dir / "mine.yaml"
    before = path.read_text()
    wrong = cli("set", "mine", "mappings.move.deadzone_zm", "1")
    assert wrong.returncode == 2 and path.read_text() == before
    assert "did you mean 'deadzone_mm'?" in wrong.stderr
    assert not re.search(re.escape(f"{path}:") + r"\d", wrong.stderr)  # a line of the changed text: past the file


def test_change_reports_print_yaml_values_not_python_ones(cli):
    assert cli("new", "mine", "--from", "accessibility").returncode == 0
    was_unset = cli("set", "mine", "mappings.move.invert_x", "true")
    assert was_unset.returncode == 0
    assert "mappings.move.invert_x: (not set) -> true" in was_unset.stdout
    undone = cli("unset", "mine", "mappings.move.invert_x")
    assert "mappings.move.invert_x: true -> removed" in undone.stdout
    smoothing = cli("set", "mine", "mappings.move.smoothing", "{beta: 0.1}")
    assert "-> {beta: 0.1}" in smoothing.stdout and "{filter: one_euro," in smoothing.stdout
    for python in ("None", "True", "False", "'beta'"):
        assert python not in was_unset.stdout + undone.stdout + smoothing.stdout


def test_mapping_a_game_again_says_which_entry_it_replaces(tmp_path):
    from helpers import run_cli

    env = {"XDG_CONFIG_HOME": str(tmp_path / "config")}
    assert run_cli("profile", "auto", "add", "4242", "mouse", env=env).returncode == 0
    again = run_cli("profile", "auto", "add", "4242", "default", env=env)
    assert again.returncode == 0 and "replacing Steam app 4242 -> mouse" in again.stdout


def test_bad_option_values_are_said_in_the_projects_words_with_the_nearest_choice():
    from helpers import run_cli

    number = run_cli("demo", "--seconds", "abc")
    assert number.returncode == 2 and "expected a number" in number.stderr
    choice = run_cli("run", "--source", "sim", "--output", "termial")
    assert choice.returncode == 2 and "did you mean 'term'?" in choice.stderr
    for library in ("Value error", "Input should be", "unable to parse"):
        assert library not in number.stderr + choice.stderr


# --- profile test: every mapped output, those never reached marked --------------------------------
def test_profile_test_lists_every_mapped_output_and_marks_those_never_reached(cli, tmp_path):
    import json

    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    path = tmp_path / "up.jsonl"  # rest, a 4 mm push up for 1 s, rest: nothing else
    rows = []
    for i in range(300):
        pushing = 50 <= i < 150
        e = GestureEstimate(
            t_us=i * 10_000,
            gesture=GestureType.PUSH if pushing else GestureType.NONE,
            resting=not pushing,
            intensity_mm=4.0 if pushing else 0.0,
            translation_mm=[0.0, 1.5] if pushing else [0.0, 0.0],
        )
        rows.append(json.dumps(e.to_json_dict()))
    path.write_text("\n".join(rows) + "\n")
    shown = cli("test", "accessibility", "--source", str(path), "--every-ms", "1000")
    assert shown.returncode == 0, shown.stderr
    lines = {line.split()[1]: line for line in shown.stdout.splitlines() if line.startswith("│ ") and "press" in line}
    assert set(lines) == {"dpad_up", "dpad_down", "dpad_left", "dpad_right", "A", "B"}  # as the profile writes them
    assert "never reached" not in lines["dpad_up"] and "never reached" in lines["dpad_down"]
    assert "never reached: dpad_down, dpad_left, dpad_right, A (BTN_SOUTH), B (BTN_EAST)" in shown.stdout
    as_json = json.loads(cli("test", "accessibility", "--source", str(path), "--json").stdout)
    assert {o["output"]: o["reached"] for o in as_json["outputs"]}["dpad_left"] is False


# --- calibrate: a calibration its own check finds wrong is not written ----------------------------
def test_a_calibration_the_check_finds_wrong_is_written_only_with_force(tmp_path):
    from helpers import run_cli

    out = tmp_path / "sensor.yaml"
    flags = ("calibrate", "--source", "sim", "--sim-rotation", "90", "--mirror", "--rotation", "0", "--out", str(out))
    refused = run_cli(*flags)
    assert refused.returncode == 1, refused.stdout + refused.stderr
    assert not out.exists() and "nothing written" in refused.stdout and "--force" in refused.stdout
    assert "use it with --sensor" not in refused.stdout
    # the orientation came from options: the advice names the options, not pushes never asked for
    assert "give, instead of --mirror --rotation 0, --mirror --rotation 90" in refused.stdout
    assert "push exactly the ways asked" not in refused.stdout
    forced = run_cli(*flags, "--force")
    assert forced.returncode == 1 and out.is_file() and "written with --force" in forced.stdout


# --- help: -h everywhere, an example on every page, the main page leads with where to start ---------
def _command_paths() -> list[tuple[str, ...]]:
    import typer

    from neurotouch_hid.cli import app

    paths = []

    def walk(command, path):
        paths.append(path)
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return paths


def _help(monkeypatch, capsys, *args: str) -> str:
    from neurotouch_hid.cli import main

    monkeypatch.setattr(sys, "argv", ["neurotouch-hid", *args])
    capsys.readouterr()
    with pytest.raises(SystemExit) as done:
        main()
    out = capsys.readouterr().out
    assert done.value.code == 0, (args, out)
    return out


def test_every_command_takes_h_and_its_help_ends_with_an_example_of_its_own_options(monkeypatch, capsys):
    import typer

    from neurotouch_hid.cli import EXAMPLES, app

    paths = _command_paths()
    assert len(paths) > 25
    root = typer.main.get_command(app)
    for path in paths[1:]:
        page = _help(monkeypatch, capsys, *path, "-h")
        assert page.startswith("Usage: ") and f"neurotouch-hid {' '.join(path)}" in page.splitlines()[0], path
        assert "\n  Example" in page, path
        for example in EXAMPLES[" ".join(path)]:
            assert f"    {example}" in page
            words = example.split()
            words = words[next(i for i, w in enumerate(words) if "neurotouch-hid" in w) + 1 :]  # sudo "$(...)"
            assert " ".join(words).startswith(" ".join(path)), example
            command = root  # the command the example runs
            while words and words[0] in getattr(command, "commands", {}):
                command = command.commands[words.pop(0)]
            options = {opt for param in command.params for opt in param.opts + param.secondary_opts}
            assert all(word in options for word in words if word.startswith("--")), example


def test_the_main_help_leads_with_demo_doctor_and_the_guide(monkeypatch, capsys):
    page = _help(monkeypatch, capsys, "-h")
    commands = page.split("Commands:\n")[1].split()
    assert commands[0] == "demo" and "doctor" in commands[:15] and commands.index("doctor") < commands.index("info")
    listed = [line.split()[0] for line in page.split("Commands:\n")[1].splitlines() if line.startswith("  ")]
    assert listed[:2] == ["demo", "doctor"]
    assert "docs/getting-started.md" in page and "neurotouch-hid demo" in page.split("Options:")[0]


# --- a sensor.yaml that does not fit the recording is named, and so is what it did ----------------
def _off_by_12_px(tmp_path, recording) -> Path:
    """``recording`` in a folder of its own beside a sensor.yaml whose rest layout is 12 px off."""
    from neurotouch_hid.sources.simulator import SimulatedSource

    folder = tmp_path / "rec"
    folder.mkdir()
    copy = folder / "rec.aedat4"
    copy.write_bytes(recording.read_bytes())
    rest = SimulatedSource(seed=0).rest_px
    sensor = SimulatedSource(seed=0).sensor
    text = (
        f"width: {sensor.width}\nheight: {sensor.height}\npx_per_mm: {sensor.px_per_mm}\n"
        f"gel_center_px: [{sensor.gel_center_px[0]}, {sensor.gel_center_px[1]}]\n"
        f"gel_radius_px: {sensor.gel_radius_px}\nmirror: true\nrotation_deg: 0.0\nrest_markers_px:\n"
        + "".join(f"- [{x + 12:.2f}, {y:.2f}]\n" for x, y in rest)
    )
    (folder / "sensor.yaml").write_text(text)
    return copy


def test_track_names_the_sensor_yaml_no_frame_matched_and_what_to_try(tmp_path, sim_gel_short_recording):
    from helpers import run_cli

    recording = _off_by_12_px(tmp_path, sim_gel_short_recording)  # 38 frames, the gel pressed from 0.6 s
    done = run_cli("track", str(recording), "--out", str(tmp_path / "p.jsonl"))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    said = done.stderr
    assert "no APS frame found" not in said
    assert f"none of its 38 APS frames matched the gel at rest in {recording.parent / 'sensor.yaml'}" in said
    assert "--sensor" in said and "calibrate" in said


def test_track_says_why_its_windows_start_late(tmp_path):
    from conftest import write_chunks
    from helpers import run_cli

    from neurotouch_hid.sources.simulator import SimulatedSource

    still = list(SimulatedSource(seed=0, gestures=["pinch"]).chunks(2.5))  # at rest for the first 0.6 s
    recording = _off_by_12_px(tmp_path, write_chunks(tmp_path / "still.aedat4", still))
    done = run_cli("track", str(recording), "--out", str(tmp_path / "p.jsonl"))
    assert done.returncode == 0, done.stderr
    assert f"(geometry: {recording.parent / 'sensor.yaml'})" in done.stdout
    assert "did not match the gel at rest" in done.stderr and "the windows start" in done.stderr


# --- the demo ends on the gel at rest, and its t counter goes with the windows ----------------------
def test_the_demos_hand_finishes_its_gesture_before_the_stream_ends():
    from neurotouch_hid.sources import Performed
    from neurotouch_hid.sources.open import FINISH_GESTURE_S, simulated_items
    from neurotouch_hid.sources.simulator import SimulatedSource

    def labels(finish: bool) -> list:
        items = simulated_items(SimulatedSource(seed=0), 2.0, 10_000, labelled=True, finish=finish)
        return [item.label for item in items if isinstance(item, Performed)]

    cut = labels(False)  # the first push, from 0.6 s, is held at 2 s
    assert cut[-1].gesture.value == "push" and len(cut) == 50
    finished = labels(True)
    assert [label.t_us for label in finished[: len(cut)]] == [label.t_us for label in cut]  # the same run, longer
    assert finished[-1].gesture.value == "none" and finished[-1].resting
    assert all(label.resting for label in finished[-12:])  # half a second at rest at the end
    assert len(finished) * 0.04 <= 2.0 + FINISH_GESTURE_S


def test_the_live_views_t_counts_from_the_first_window_as_the_windows_do():
    import io

    from rich.console import Console

    from neurotouch_hid.core.controller import ControllerState
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType
    from neurotouch_hid.core.stages import WindowRecord
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.views.live import LiveView

    view = LiveView(Console(file=io.StringIO(), force_terminal=False, width=200))
    stats = RunStats()
    for k in range(1, 68):
        stats.windows = k
        estimate = GestureEstimate(t_us=1_000_000 + k * 10_000, gesture=GestureType.NONE, resting=True)
        state = ControllerState.neutral(estimate.t_us)
        record = WindowRecord(
            estimate, state, k == 1, False, load_profile("default"), "default", None, None, None, True, stats, None
        )
        view.publish(record)
    shown = Console(file=io.StringIO(), width=120, color_system=None)
    shown.print(view.__rich__())
    footer = [line for line in shown.file.getvalue().splitlines() if "windows 67" in line]
    view.close()
    assert footer and "t 0.660 s" in footer[0]  # 66 windows of 10 ms after the first


# --- the first run's promise: the closing line says why its latency is high ----------------------
def test_the_closing_line_says_which_windows_ran_interpreted_while_compiling():
    from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

    from neurotouch_hid.core.stages import CompileProgress
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions

    compiling = iter([CompileProgress("compiling", k / 5) for k in range(5)])

    def progress():  # the compile lasts five windows, then the pipeline is compiled
        return next(compiling, None)

    stream = [batch(k * 1000) for k in range(12)]
    runtime = Engine(
        RunParts(stream, FakePipeline(), compile_progress=progress),
        {"sign": 1},
        [RecordingOutput()],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    )
    stats = runtime.run()
    assert stats.windows == 12 and 1 <= stats.interpreted_windows < 12
    # a fast run reads its source ahead: what the compile left queued is counted apart from the rest
    assert stats.interpreted_windows + stats.queued_windows + len(stats.compiled_latency) == 12
    assert f"{stats.interpreted_windows} windows ran interpreted" in stats.summary()


def test_a_run_that_ends_before_its_compile_does_not_promise_a_compiled_next_run():
    """A short demo on a fresh two-core machine ends before its ~30 s compile: the compile's
    children are stopped with the run (what they cached stays), so the next run goes on compiling.
    The closing line says how far it got, not that the next run starts compiled."""
    from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

    from neurotouch_hid.core.stages import CompileProgress
    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions

    stats = Engine(
        RunParts(
            [batch(k * 1000) for k in range(12)],
            FakePipeline(),
            compile_progress=lambda: CompileProgress("compiling", 0.625),
        ),
        {"sign": 1},
        [RecordingOutput()],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    line = stats.summary()
    assert stats.interpreted_windows == 12 and stats.compile_ended_at == 0.625
    assert "the next run starts compiled" not in line and "first run only" not in line, line
    said = "the run ended with the compile 62 % done: what it compiled is cached, the next run compiles the rest"
    assert said in line, line


def test_the_queue_the_compile_left_is_kept_out_of_the_compiled_latency():
    from neurotouch_hid.core.stats import RunStats

    stats = RunStats()
    for _ in range(3):  # interpreted, 500 ms each
        stats.add_latency(1, 500_000_000, compiling=True, waiting=4)
    for waiting in (3, 2, 0):  # compiled now, but read while it compiled: 600 ms behind
        stats.add_latency(1, 600_000_000, compiling=False, waiting=waiting)
    for _ in range(5):  # caught up: 2 ms, even when the source queues ahead again
        stats.add_latency(1, 2_000_000, compiling=False, waiting=2)
    stats.windows = 11
    counted = (stats.interpreted_windows, stats.queued_windows, len(stats.compiled_latency), len(stats.latency))
    assert counted == (3, 3, 5, 11)
    line = stats.summary()
    assert (
        "3 windows ran interpreted, slowly, while the pipeline compiled, 3 more from the items queued meanwhile" in line
    )
    assert "once compiled: p50 2.00 ms p99 2.00 ms" in line


def test_a_run_that_compiled_before_its_first_window_counts_every_window_as_compiled():
    from neurotouch_hid.core.stats import RunStats

    stats = RunStats()
    for waiting in (5, 0, 3):
        stats.add_latency(1, 1_000_000, compiling=False, waiting=waiting)
    assert (stats.interpreted_windows, stats.queued_windows, len(stats.compiled_latency)) == (0, 0, 3)
    assert "interpreted" not in stats.summary()


def test_a_run_without_a_compile_says_nothing_of_it():
    from runtime_fakes import FakeMapper, FakePipeline, RecordingOutput, batch

    from neurotouch_hid.engine.engine import Engine, RunParts
    from neurotouch_hid.engine.mode import RunMode, RunOptions

    stats = Engine(
        RunParts([batch(k * 1000) for k in range(6)], FakePipeline()),
        {"sign": 1},
        [RecordingOutput()],
        RunOptions(mode=RunMode.FAST, mapper_factory=FakeMapper),
    ).run()
    assert stats.interpreted_windows == 0 and "interpreted" not in stats.summary()


def test_the_compile_message_states_the_measured_cost():
    from neurotouch_hid.service.warmup import COMPILE_COST

    performance = (Path(__file__).resolve().parents[1] / "docs" / "performance.md").read_text()
    assert "25 s of CPU" in COMPILE_COST and "busy machine" in COMPILE_COST and "two cores" not in COMPILE_COST
    start_up = performance.split("## Start-up")[1].split("\n## ")[0]
    assert "Compiling costs ~25 s of CPU" in start_up and "compile_pipeline()" in start_up


# --- smaller: install.sh --user refuses root, as its help says ---------------------------------------
def test_install_user_refuses_root_run_through_sudo(tmp_path):
    import os
    import shutil
    import subprocess

    from neurotouch_hid.service.udev import INSTALL_SCRIPT

    as_root = [] if os.geteuid() == 0 else [shutil.which("unshare") or "unshare", "--map-root-user"]
    env = {
        **os.environ,
        "HOME": str(tmp_path / "home"),
        "XDG_CONFIG_HOME": str(tmp_path / "config"),
        "SUDO_USER": "ada",
    }
    done = subprocess.run([*as_root, "sh", str(INSTALL_SCRIPT), "--user"], capture_output=True, text=True, env=env)
    assert done.returncode == 1 and "without sudo" in done.stderr
    assert not (tmp_path / "config" / "systemd").exists()


# --- smaller: no legend covers data ----------------------------------------------------------------
def _legends_over_data(monkeypatch, draw) -> list[str]:
    """The legends that overlap their axes' data area in the figures ``draw()`` makes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig) or close(fig))
    draw()
    over = []
    for fig in figures:
        fig.canvas.draw()
        for ax in fig.axes:
            legend = ax.get_legend()
            if legend is not None and legend.get_window_extent().overlaps(ax.get_window_extent()):
                over.append(f"{ax.get_title() or ax.get_ylabel()}")
    assert figures
    return over


def test_no_legend_of_the_eval_report_covers_data(monkeypatch, tmp_path):
    from test_report import result as result_fixture

    from neurotouch_hid.evaluation.report import write_figures

    result = result_fixture.__wrapped__()
    assert _legends_over_data(monkeypatch, lambda: write_figures(result, tmp_path)) == []


def test_no_legend_of_the_profile_test_plot_covers_data(monkeypatch, tmp_path):
    from neurotouch_hid.core.estimate import GestureEstimate, GestureType
    from neurotouch_hid.mapping.profile import load_profile
    from neurotouch_hid.mapping.replay import plot_timeline, replay

    estimates = [
        GestureEstimate(
            t_us=k * 10_000,
            gesture=GestureType.PUSH if 20 <= k < 60 else GestureType.NONE,
            resting=not 20 <= k < 60,
            intensity_mm=4.0 if 20 <= k < 60 else 0.0,
            translation_mm=[1.0, 1.0] if 20 <= k < 60 else [0.0, 0.0],
        )
        for k in range(100)
    ]
    states = replay(load_profile("default"), estimates)
    assert _legends_over_data(monkeypatch, lambda: plot_timeline(estimates, states, tmp_path / "t.png")) == []


# --- smaller: view's picture has a colour key and arrows that do not cross -------------------------
def test_views_picture_has_a_colour_key_and_arrows_that_stay_short_of_the_next_marker():
    import numpy as np

    from neurotouch_hid.views.pictures import arrow_scale, colour_key, draw_view

    grid = np.array([(x, y) for x in range(100, 200, 10) for y in range(80, 180, 10)], dtype=float)
    pushed = grid + [6.0, 0.0]  # a firm push: 6 px, 60 % of the 10 px pitch
    gain = arrow_scale(pushed, grid, 3.0)
    assert gain * 6.0 <= 0.8 * 10.0 + 1e-9 and gain < 3.0
    assert arrow_scale(grid + [0.5, 0.0], grid, 3.0) == 3.0  # small moves: the full gain
    picture = draw_view(np.full((260, 346), 40, np.uint8), np.zeros(0, dtype=[("x", "i2")]), pushed, grid, None)
    corner = picture[-110:, :30].reshape(-1, 3)
    for label, colour in colour_key(gain):
        assert (corner == colour).all(axis=1).any(), label


def test_record_says_what_it_wrote(tmp_path):
    from helpers import run_cli

    out = tmp_path / "rec.aedat4"
    done = run_cli("record", str(out), "--source", "sim", "--seconds", "1", "--fast")
    assert done.returncode == 0, done.stderr
    assert f"wrote {out}: 1.00 s," in done.stdout and "APS frames" in done.stdout
