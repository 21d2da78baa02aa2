"""The repository stands alone and installs one package: a copy anywhere collects every test."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from tests.conftest import REPO

# A path that leaves the repository for the sibling folders the project once read from.
OUTSIDE = re.compile(r"\.\." + r"/(shared|fixtures|design)\b")


def _files() -> list[Path]:
    """Tracked and untracked-but-not-ignored files: what a clone (or the next commit) holds."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout
    return [REPO / name for name in listed.decode().split("\0") if name]


def _collected(root: Path) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, f"collection failed in {root}:\n{out.stdout[-3000:]}{out.stderr}"
    return {line for line in out.stdout.splitlines() if "::" in line}


def _copy(root: Path) -> None:
    """What a clone holds, links as links (capsd/services and capsd/simulator are links)."""
    for path in _files():
        target = root / path.relative_to(REPO)
        target.parent.mkdir(parents=True, exist_ok=True)
        if path.is_symlink():
            target.symlink_to(path.readlink())
        elif path.is_file():
            shutil.copy2(path, target)


def test_no_file_reads_or_links_outside_the_repository() -> None:
    offenders = []
    for path in _files():
        if not path.is_file() or path.suffix in {".png", ".pt", ".raw", ".mcap"}:
            continue
        text = path.read_text(errors="replace")
        offenders += [
            f"{path.relative_to(REPO)}:{n}"
            for n, line in enumerate(text.splitlines(), 1)
            if OUTSIDE.search(line)
        ]
    assert not offenders, f"paths outside the repository: {offenders}"


def test_a_copy_in_another_folder_collects_every_test(tmp_path: Path) -> None:
    # A folder with no sibling `shared/`: what a fresh clone anywhere looks like.
    clone = tmp_path / "elsewhere" / "capsd"
    _copy(clone)
    assert not (clone.parent / "shared").exists()
    here = _collected(REPO)
    there = _collected(clone)
    assert len(here) > 100
    assert there == here


def test_the_wheel_installs_one_top_level_package(tmp_path: Path) -> None:
    # Generic names such as `services` or `simulator` in site-packages collide with other
    # software: the folders are mapped into capsd (capsd.services, capsd.simulator).
    source = tmp_path / "source"
    _copy(source)
    out = subprocess.run(
        [
            *(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q"),
            *("--disable-pip-version-check", "-w", str(tmp_path / "wheel"), str(source)),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    (wheel,) = (tmp_path / "wheel").glob("capsd-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    top = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert top == {"capsd"}
    for module in (
        "capsd/services/locator/service.py",
        "capsd/simulator/service.py",
        "capsd/services/sonar_detect/weights/polar_net.pt",
        "capsd/py.typed",
    ):
        assert module in names, f"{module} is not in the wheel"
