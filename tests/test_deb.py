"""The packages: the .deb (packaging/build-deb.sh) and the wheel and sdist.

The fast test stages the package's own files (no venv, no root). The slow ones (``-m slow``,
left out of the default run; packaging/README.md names the commands) build the real .deb in a
Debian 12 root, check its contents and metadata (lintian where installed: every tag it reports
is explained in packaging/README.md), install it into a clean Debian 12 root, run it from the
installed files only, purge it and check nothing is left but user files; and build the wheel
and sdist and install the wheel with pipx.
"""

from __future__ import annotations

import gzip
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest
from kernel.vm import installed

REPO = Path(__file__).resolve().parent.parent
PACKAGING = REPO / "packaging"
VERSION = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
PREFIX = "opt/neurotouch-hid"
#: The files of the package that do not come from the venv, as build-deb.sh stages them.
OWN_FILES = {
    "usr/bin/neurotouch-hid",
    "usr/lib/udev/rules.d/60-neurotouch.rules",
    "usr/lib/modules-load.d/neurotouch-hid.conf",
    "usr/lib/systemd/user/neurotouch-hid.service",
    "usr/lib/systemd/user/neurotouch-hid@.service",
    "usr/share/doc/neurotouch-hid/README.md",
    "usr/share/doc/neurotouch-hid/changelog.Debian.gz",
    "usr/share/doc/neurotouch-hid/copyright",
}
#: What only the full build adds beside the venv: completion and the man page.
BUILT_FILES = {
    "usr/share/bash-completion/completions/neurotouch-hid",
    "usr/share/zsh/vendor-completions/_neurotouch-hid",
    "usr/share/fish/vendor_completions.d/neurotouch-hid.fish",
    "usr/share/man/man1/neurotouch-hid.1.gz",
}


def _control(text: str) -> dict[str, str]:
    fields, key = {}, None
    for line in text.splitlines():
        if line.startswith(" ") and key:
            fields[key] += "\n" + line
        elif ":" in line:
            key, value = line.split(":", 1)
            fields[key] = value.strip()
    return fields


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if not p.is_dir()}


def test_the_staged_package_has_its_files_control_fields_and_maintainer_scripts(tmp_path):
    stage = tmp_path / "stage"
    result = subprocess.run(
        [str(PACKAGING / "build-deb.sh"), "--stage-only", str(stage)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert _files(stage) - {f for f in _files(stage) if f.startswith("DEBIAN/")} == OWN_FILES
    assert os.readlink(stage / "usr/bin/neurotouch-hid") == f"/{PREFIX}/bin/neurotouch-hid"
    assert (stage / "usr/lib/modules-load.d/neurotouch-hid.conf").read_text() == "uinput\n"
    assert (stage / "usr/lib/udev/rules.d/60-neurotouch.rules").read_bytes() == (
        REPO / "udev/60-neurotouch.rules"
    ).read_bytes()
    unit = (stage / "usr/lib/systemd/user/neurotouch-hid.service").read_text()
    execs = re.findall(r"^Exec\w*=(\S+)", unit, re.M)
    assert execs and set(execs) == {"/usr/bin/neurotouch-hid"}, execs  # no PATH lookup, no checkout
    template = (stage / "usr/lib/systemd/user/neurotouch-hid@.service").read_text()  # one driver per camera
    assert re.search(r"^ExecStart=/usr/bin/neurotouch-hid run --source davis --serial %i ", template, re.M)
    arch = subprocess.run(["dpkg", "--print-architecture"], capture_output=True, text=True).stdout.strip()
    control = _control((stage / "DEBIAN/control").read_text())
    assert control["Package"] == "neurotouch-hid"
    assert control["Version"] == f"{VERSION}-1"
    assert control["Architecture"] == arch
    assert "python3.11" in control["Depends"]  # the venv's interpreter is Debian 12's
    assert int(control["Installed-Size"]) > 0
    assert control["Description"].startswith("NeuroTouch soft tactile sensor as a game controller\n ")
    sums = dict(reversed(line.split(None, 1)) for line in (stage / "DEBIAN/md5sums").read_text().splitlines())
    assert set(sums) == OWN_FILES - {"usr/bin/neurotouch-hid"}  # every regular file, the symlink not
    for script in ("postinst", "prerm", "postrm"):
        path = stage / "DEBIAN" / script
        assert os.access(path, os.X_OK), script
        syntax = subprocess.run(["sh", "-n", str(path)], capture_output=True, text=True)
        assert syntax.returncode == 0, syntax.stderr
    with gzip.open(stage / "usr/share/doc/neurotouch-hid/changelog.Debian.gz", "rt") as changelog:
        assert changelog.readline().startswith(f"neurotouch-hid ({VERSION}-1) ")


# --- slow: the real package ----------------------------------------------------------------------
def _sh(*argv: str, timeout: float = 3600, check: bool = True, **kw) -> subprocess.CompletedProcess:
    result = subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout, **kw)
    if check:
        assert result.returncode == 0, (
            f"{argv}: exit {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
        )
    return result


def _in_root(root: Path, command: str, check: bool = True, timeout: float = 1800) -> subprocess.CompletedProcess:
    return _sh(str(PACKAGING / "debian12-root.sh"), "chroot", str(root), command, check=check, timeout=timeout)


#: Not compared before install and after purge: the kernel's and the tools' own state, and the
#: users' homes (their configuration and caches are theirs to keep).
NOT_COMPARED = (
    "proc",
    "sys",
    "dev",
    "run",
    "tmp",
    "var/log",
    "var/cache",
    "var/lib/apt",
    "var/lib/dpkg",
    "home",
    "root",
)


def _snapshot(root: Path) -> dict[str, tuple]:
    """Every path of the root (outside NOT_COMPARED): kind, size and mode."""
    found = {}
    for folder, dirs, files in os.walk(root):
        rel = os.path.relpath(folder, root)
        dirs[:] = [d for d in dirs if os.path.normpath(os.path.join(rel, d)) not in NOT_COMPARED]
        for name in dirs + files:
            path = os.path.join(folder, name)
            st = os.lstat(path)
            kind = "dir" if os.path.isdir(path) and not os.path.islink(path) else "file"
            found[os.path.normpath(os.path.join(rel, name))] = (kind, st.st_size if kind == "file" else 0, st.st_mode)
    return found


def _lintian_explained() -> set[str]:
    """The lintian tags packaging/README.md explains (``tag-name`` in its lintian section)."""
    text = (PACKAGING / "README.md").read_text()
    section = text.split("## lintian", 1)[1].split("\n## ", 1)[0]
    return set(re.findall(r"`([a-z0-9][a-z0-9+.-]+)`", section))


@pytest.fixture(scope="module")
def deb() -> Path:
    """The .deb, built by packaging/build-deb.sh (slow: the venv is built in a Debian 12 root);
    ``NEUROTOUCH_DEB=dist/...deb`` tests one built before instead."""
    assert os.geteuid() == 0, "building and installing the .deb needs root (debootstrap, chroot): run as root"
    found = installed("debootstrap", "debootstrap")  # apt-installed when missing, as the kernel tests' qemu
    assert found, "needs debootstrap, which apt-get could not install: apt-get install debootstrap"
    if os.environ.get("NEUROTOUCH_DEB"):
        return Path(os.environ["NEUROTOUCH_DEB"]).resolve()
    out = _sh(str(PACKAGING / "build-deb.sh"), timeout=7200).stdout.strip().splitlines()[-1]
    path = Path(out)
    assert path.is_file() and path.parent == REPO / "dist", out
    return path


@pytest.mark.slow
def test_the_deb_holds_the_driver_its_venv_and_system_files_and_nothing_of_the_checkout(deb, tmp_path):
    arch = _sh("dpkg", "--print-architecture").stdout.strip()
    assert deb.name == f"neurotouch-hid_{VERSION}-1_{arch}.deb"
    info = _control(_sh("dpkg-deb", "--field", str(deb)).stdout)
    assert info["Version"] == f"{VERSION}-1" and "python3.11" in info["Depends"]
    tree = tmp_path / "tree"
    _sh("dpkg-deb", "-x", str(deb), str(tree))
    files = _files(tree)
    assert OWN_FILES | BUILT_FILES <= files
    assert f"{PREFIX}/bin/neurotouch-hid" in files and f"{PREFIX}/pyvenv.cfg" in files
    site = f"{PREFIX}/lib/python3.11/site-packages"
    for shipped in (REPO / "neurotouch_hid/profiles").glob("*.yaml"):
        assert f"{site}/neurotouch_hid/profiles/{shipped.name}" in files
    target = os.readlink(tree / PREFIX / "bin/python3")
    if not target.startswith("/"):  # python3 -> python3.11 -> the interpreter
        target = os.readlink(tree / PREFIX / "bin" / target)
    assert target == "/usr/bin/python3.11", target  # Debian 12's, the one Depends names
    assert (tree / PREFIX / "bin/neurotouch-hid").read_text().startswith(f"#!/{PREFIX}/bin/python")
    assert "home = /usr/bin" in (tree / PREFIX / "pyvenv.cfg").read_text()
    assert any(f.startswith(f"{site}/numba/") for f in files) and any(f.startswith(f"{site}/evdev/") for f in files)
    leaks = _sh("grep", "-rlsF", str(REPO), str(tree), check=False).stdout.split()
    assert not leaks, f"files that name the checkout: {leaks[:10]}"
    with gzip.open(tree / "usr/share/man/man1/neurotouch-hid.1.gz", "rt") as man:
        page = man.read()
    assert page.startswith('.\\" DO NOT MODIFY') or ".TH NEUROTOUCH-HID" in page
    assert '.SS "neurotouch-hid profile auto add"' in page and '.SS "neurotouch-hid run"' in page
    assert (
        "_NEUROTOUCH_HID_COMPLETE=complete_bash"
        in (tree / "usr/share/bash-completion/completions/neurotouch-hid").read_text()
    )
    if shutil.which("lintian"):
        report = _sh("lintian", "--tag-display-limit", "0", str(deb), check=False, timeout=3600)
        tags = set(re.findall(r"^[EWIP]: neurotouch-hid[^:]*: ([a-z0-9][a-z0-9+.-]+)", report.stdout, re.M))
        unexplained = tags - _lintian_explained()
        assert not unexplained, (
            f"lintian tags not explained in packaging/README.md: {sorted(unexplained)}\n{report.stdout[-4000:]}"
        )


@pytest.mark.slow
def test_the_deb_installs_runs_and_purges_in_a_clean_debian_12(deb, tmp_path):
    """A fresh Debian 12 root (cached debootstrap, copied); the package's dependencies from
    Debian's archive; then the installed files only: `--version`, `doctor` and `demo --seconds 2`
    as a user and the demo as root; purge; nothing left but the users' files."""
    root = tmp_path / "debian12"
    _sh(str(PACKAGING / "debian12-root.sh"), "copy", str(root))
    try:
        _in_root(
            root, "apt-get update -q && apt-get install -y -q --no-install-recommends python3.11 && useradd -m player"
        )
        before = _snapshot(root)
        shutil.copy(deb, root / "tmp" / deb.name)
        _in_root(root, f"apt-get install -y -q --no-install-recommends /tmp/{deb.name}")
        assert "Status: install ok installed" in _in_root(root, "dpkg -s neurotouch-hid").stdout
        player = "runuser -u player -- env HOME=/home/player XDG_RUNTIME_DIR=/tmp/player PATH=/usr/bin:/bin"
        _in_root(root, "mkdir -m 700 /tmp/player && chown player /tmp/player")

        version = _in_root(root, f"cd /home/player && {player} neurotouch-hid --version", check=False)
        assert version.returncode == 0 and VERSION in version.stdout, version
        doctor = _in_root(root, f"cd /home/player && {player} neurotouch-hid doctor", check=False)
        assert doctor.returncode in (0, 1) and "Traceback" not in doctor.stderr, doctor  # 1: no camera here
        assert "/usr/lib/udev/rules.d/60-neurotouch.rules" in doctor.stdout, doctor.stdout
        assert "/usr/lib/systemd/user/neurotouch-hid.service" in doctor.stdout, doctor.stdout
        demo = _in_root(root, f"cd /home/player && {player} neurotouch-hid demo --seconds 2", check=False)
        assert demo.returncode == 0, demo
        assert "no writable /dev/uinput" in demo.stderr and "windows" in demo.stderr, demo.stderr
        added = _in_root(root, f"cd /home/player && {player} neurotouch-hid profile auto add 4242 mouse", check=False)
        assert added.returncode == 0, added
        completion = _in_root(
            root,
            "bash -c '. /usr/share/bash-completion/completions/neurotouch-hid; COMP_WORDS=(neurotouch-hid profile au);"
            " COMP_CWORD=2; _neurotouch_hid_completion neurotouch-hid; echo ${COMPREPLY[@]}'",
        )
        assert completion.stdout.split() == ["auto"], completion
        as_root = _in_root(root, "cd /root && neurotouch-hid demo --seconds 2", check=False)
        assert as_root.returncode == 0, as_root
        written = _in_root(root, "find /opt/neurotouch-hid -newer /tmp/player -type f | wc -l").stdout.strip()

        _in_root(root, "apt-get purge -y -q neurotouch-hid")
        after = _snapshot(root)
        assert _in_root(root, "dpkg -s neurotouch-hid", check=False).returncode != 0
        assert (root / "home/player/.config/neurotouch-hid/games.yaml").is_file()  # the user's, kept
    finally:
        subprocess.run(["umount", str(root / "proc")], capture_output=True)
    added_paths = sorted(set(after) - set(before))
    removed_paths = sorted(set(before) - set(after))
    changed = sorted(p for p in set(before) & set(after) if before[p] != after[p] and before[p][0] == "file")
    assert not added_paths and not removed_paths and not changed, (
        f"left after purge: {added_paths[:20]}; gone: {removed_paths[:20]}; changed: {changed[:20]}"
    )
    assert int(written) > 0, "root's demo wrote nothing into /opt (numba's cache): prerm's cleanup went untested"


@pytest.mark.slow
def test_the_wheel_and_sdist_build_and_pipx_installs_the_wheel(tmp_path):
    out = tmp_path / "dist"
    _sh(sys.executable, "-m", "build", "--outdir", str(out), str(REPO), timeout=1800)
    wheel = next(out.glob("neurotouch_hid-*.whl"))
    sdist = next(out.glob("neurotouch_hid-*.tar.gz"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "neurotouch_hid/profiles/default.yaml" in names and "neurotouch_hid/games.py" in names
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "neurotouch-hid = neurotouch_hid.cli:main" in zipfile.ZipFile(wheel).read(entry).decode()
    members = tarfile.open(sdist).getnames()
    for shipped in ("udev/60-neurotouch.rules", "packaging/build-deb.sh", "packaging/debian/postinst"):
        assert any(m.endswith("/" + shipped) for m in members), shipped  # the sdist builds the .deb too
    env = dict(
        os.environ,
        PIPX_HOME=str(tmp_path / "pipx"),
        PIPX_BIN_DIR=str(tmp_path / "bin"),
        PIPX_MAN_DIR=str(tmp_path / "man"),
    )
    env.pop("PYTHONPATH", None)
    _sh(sys.executable, "-m", "pipx", "install", "--python", sys.executable, str(wheel), env=env, timeout=3600)
    exe = tmp_path / "bin" / "neurotouch-hid"
    listed = _sh(str(exe), "profile", "list", env=env, cwd=str(tmp_path))
    assert "default" in listed.stdout and "spacecraft" in listed.stdout
    where = _sh(str(exe), "profile", "path", "default", env=env, cwd=str(tmp_path)).stdout.strip()
    assert where.startswith(str(tmp_path / "pipx")), where  # the pipx venv's files, not the checkout
