"""Every example of docs/formats.md runs as written (one per format)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "formats.md"
SECTIONS = re.split(r"^## ", DOC.read_text(), flags=re.MULTILINE)[1:]
EXAMPLES = [(section.splitlines()[0], code) for section in SECTIONS
            for code in re.findall(r"^```python\n(.*?)^```", section, re.MULTILINE | re.DOTALL)]


def test_every_format_has_an_example():
    assert [title.split()[0] for title, _ in EXAMPLES] == ["NPZ", "CSV", "MATLAB", "HDF5",
                                                           "UFF"]


@pytest.mark.parametrize("title, code", EXAMPLES, ids=[t.split()[0] for t, _ in EXAMPLES])
def test_the_example_runs(title, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"docs/formats.md ({title})", "exec"), {})
