"""The optional extras (plots, video): a command that needs a missing one says which to install,
exits 2 and shows no traceback; the driver's commands and ``view --out FILE.png`` need neither.

A missing extra is simulated in a fresh process: ``sys.modules[name] = None`` makes every import
of ``name`` fail, as it does where the distribution is not installed.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from neurotouch_hid.service.extras import MissingExtraError, require, require_ffmpeg


def cli_without(blocked: list[str], *args: str) -> subprocess.CompletedProcess:
    """``neurotouch-hid ARGS`` in a fresh process in which ``blocked`` modules cannot be imported."""
    code = (
        "import runpy, sys\n"
        f"sys.modules.update(dict.fromkeys({blocked!r}))\n"
        f"sys.argv = ['neurotouch-hid', *{list(args)!r}]\n"
        "runpy.run_module('neurotouch_hid.cli', run_name='__main__')\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=300
    )


def assert_names_the_extra(result: subprocess.CompletedProcess, extra: str, dists: str) -> None:
    assert result.returncode == 2, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    assert f"pipx inject neurotouch-hid {dists}" in result.stderr, result.stderr
    assert f"pip install 'neurotouch-hid[{extra}]'" in result.stderr, result.stderr


@pytest.fixture()
def pushes(tmp_path):
    """A predictions file of 1 s: rest, then a push."""
    import json

    from neurotouch_hid.core.estimate import GestureEstimate, GestureType

    lines = []
    for i in range(100):
        push = i >= 50
        e = GestureEstimate(
            t_us=i * 10_000,
            gesture=GestureType.PUSH if push else GestureType.NONE,
            resting=not push,
            intensity_mm=3.0 if push else 0.0,
        )
        lines.append(json.dumps(e.to_json_dict()))
    path = tmp_path / "pushes.jsonl"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_profile_test_plot_without_matplotlib_names_the_plots_extra(pushes, tmp_path):
    png = tmp_path / "t.png"
    result = cli_without(["matplotlib"], "profile", "test", "default", "--source", str(pushes), "--plot", str(png))
    assert_names_the_extra(result, "plots", "matplotlib")
    assert "profile test --plot" in result.stderr
    assert "python3-matplotlib" in result.stderr
    assert not png.exists()


def test_view_mp4_and_gif_without_imageio_name_the_video_extra(sim_rest_dataset, tmp_path):
    recording = sim_rest_dataset / "u0_push.aedat4"
    for suffix in (".mp4", ".gif"):
        out = tmp_path / f"v{suffix}"
        result = cli_without(["imageio", "imageio_ffmpeg", "PIL"], "view", str(recording), "--out", str(out))
        assert_names_the_extra(result, "video", "imageio imageio-ffmpeg pillow")
        assert f"view --out FILE{suffix}" in result.stderr
        assert not out.exists()
    gif = tmp_path / "v.gif"
    result = cli_without(["PIL"], "view", str(recording), "--out", str(gif))
    assert_names_the_extra(result, "video", "imageio imageio-ffmpeg pillow")
    assert "needs pillow" in result.stderr and "python3-pil" in result.stderr
    assert not gif.exists()


def test_view_png_needs_no_extra(sim_rest_dataset, tmp_path):
    out = tmp_path / "v.png"
    result = cli_without(
        ["imageio", "imageio_ffmpeg", "matplotlib", "PIL"],
        "view",
        str(sim_rest_dataset / "u0_push.aedat4"),
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_require_passes_when_installed_and_names_the_module_otherwise(monkeypatch):
    require("plots", "eval --report")  # the test extra installs every extra
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(
        MissingExtraError, match=r"imageio-ffmpeg, which is not installed \(the optional extra \[video\]\)"
    ):
        require("video", "view --out FILE.mp4")


def test_mp4_without_an_ffmpeg_program_says_to_install_ffmpeg(monkeypatch):
    import imageio_ffmpeg

    def no_ffmpeg():
        raise RuntimeError("No ffmpeg exe could be found.")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", no_ffmpeg)
    with pytest.raises(MissingExtraError, match="sudo apt install ffmpeg"):
        require_ffmpeg("view --out FILE.mp4")


def test_the_driver_commands_import_neither_extra():
    code = (
        "import sys\n"
        "import neurotouch_hid.cli, neurotouch_hid.engine.driver, neurotouch_hid.pipeline.track\n"
        "print(sorted(m for m in ('matplotlib', 'imageio', 'imageio_ffmpeg') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_eval_report_without_matplotlib_says_so_before_evaluating(sim_rest_dataset, tmp_path):
    report = tmp_path / "report"
    json_out = tmp_path / "m.json"
    result = cli_without(
        ["matplotlib"], "eval", str(sim_rest_dataset), "--report", str(report), "--json", str(json_out)
    )
    assert_names_the_extra(result, "plots", "matplotlib")
    assert "eval --report" in result.stderr
    assert not report.exists() and not json_out.exists()  # nothing evaluated, nothing half-written
