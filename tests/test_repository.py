"""The repository stands alone: a copy anywhere collects every test, nothing reads outside it."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
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
    for path in _files():
        if path.is_file():
            target = clone / path.relative_to(REPO)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)
    assert not (clone.parent / "shared").exists()
    here = _collected(REPO)
    there = _collected(clone)
    assert len(here) > 100
    assert there == here
