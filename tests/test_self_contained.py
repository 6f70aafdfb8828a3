"""The project stands on its own: no file it ships or documents refers to method or design
notes outside the repository; the method page is docs/science.md."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = ("method.md", "design.md", "../shared", "style.md")


def _tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / name for name in out if (ROOT / name).suffix in (".py", ".md", ".toml", "")
            and (ROOT / name).is_file()]


def test_no_reference_outside_the_repository():
    offenders = []
    for path in _tracked_files():
        if path.name == Path(__file__).name:
            continue
        text = path.read_text(errors="replace")
        offenders += [f"{path.relative_to(ROOT)}: {word}" for word in OUTSIDE if word in text]
    assert not offenders, offenders


def test_science_page_has_the_numbered_sections_others_cite():
    text = (ROOT / "docs" / "science.md").read_text()
    for n in range(1, 9):
        assert f"\n## {n}. " in text, n
