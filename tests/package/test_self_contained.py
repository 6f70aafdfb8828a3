"""The project stands on its own: every page a shipped or documented file names is in the
repository (or is a page msleak writes), and every relative path leads to a file in it; the
method page is docs/science.md."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Markdown pages msleak writes into its output folders (paper, leakage, forecast).
WRITTEN_PAGES = {"report.md", "stats.md", "forecast.md"}
#: Markdown pages the scripts write into theirs (scripts/crosscheck).
SCRIPT_PAGES = {"crosscheck.md"}
PAGE_NAME = re.compile(r"(?<![\w{}])[\w-]+\.md\b")
RELATIVE_PATH = re.compile(r"(?:\.\./)+[\w.-]+")


def _tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / name for name in out if (ROOT / name).suffix in (".py", ".md", ".toml", "")
            and (ROOT / name).is_file()]


def test_every_page_named_is_in_the_repository():
    files = _tracked_files()
    pages = {path.name for path in files if path.suffix == ".md"}
    offenders = [f"{path.relative_to(ROOT)}: {name}" for path in files
                 for name in sorted(set(PAGE_NAME.findall(path.read_text(errors="replace"))))
                 if name not in pages | WRITTEN_PAGES | SCRIPT_PAGES]
    assert not offenders, offenders


def test_every_relative_path_leads_to_something_in_the_repository():
    offenders = []
    for path in _tracked_files():
        for found in RELATIVE_PATH.findall(path.read_text(errors="replace")):
            target = (path.parent / found).resolve()
            if ROOT not in target.parents or not target.exists():
                offenders.append(f"{path.relative_to(ROOT)}: {found}")
    assert not offenders, offenders


def test_the_pages_msleak_writes_are_written_by_msleak():
    for folder, names in (("msleak", WRITTEN_PAGES), ("scripts", SCRIPT_PAGES)):
        source = "\n".join(p.read_text() for p in (ROOT / folder).rglob("*.py"))
        for name in names:
            assert f'"{name}"' in source, name


def test_science_page_has_the_numbered_sections_others_cite():
    text = (ROOT / "docs" / "science.md").read_text()
    for n in range(1, 9):
        assert f"\n## {n}. " in text, n
