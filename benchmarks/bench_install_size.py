"""The size of a fresh venv with the project installed, without and with the optional extras
(docs/performance.md, "Install size").

    python3 benchmarks/bench_install_size.py [--extras plots,video] [--keep DIR]

Makes a venv with this interpreter (``python -m venv``), installs the checkout into it
(``pip install .``, the newest wheels of every dependency), and prints ``du``'s size of the venv
and of its ten largest top-level entries in site-packages; then the same with ``.[EXTRAS]``.
Needs the package index (pip's own configuration).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def du_mb(path: Path) -> int:
    """``du -sm PATH`` (MiB, rounded up as du does)."""
    return int(subprocess.run(["du", "-sm", str(path)], capture_output=True, text=True, check=True).stdout.split()[0])


def measure(folder: Path, spec: str) -> None:
    """Install ``spec`` into a new venv under ``folder``; print its size and its largest parts."""
    venv = folder / ("venv" + (spec.replace(".", "").replace("[", "-").replace("]", "").replace(",", "-") or "-core"))
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    subprocess.run([*pip, f"{REPO}{spec}"], check=True)
    site = next((venv / "lib").glob("python3*/site-packages"))
    parts = sorted(((du_mb(p), p.name) for p in site.iterdir()), reverse=True)[:10]
    print(f"pip install .{spec}: {du_mb(venv)} MB; largest: " + ", ".join(f"{n} {mb}" for mb, n in parts), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--extras", default="plots,video", help="the extras of the second install")
    ap.add_argument("--keep", type=Path, default=None, help="make the venvs here and keep them")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-install-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        measure(folder, "")
        measure(folder, f"[{args.extras}]")


if __name__ == "__main__":
    main()
