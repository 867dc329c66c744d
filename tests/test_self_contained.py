"""The repository stands alone: no tracked file cites a path outside it (a user's clone
has no sibling folders), and the design notes the code cites are in docs/."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# A path into a folder beside the repository (../notes/..., ../notes.md), or design
# notes other than docs/design.md. An attack string such as ``../x`` cites nothing.
OUTSIDE = re.compile(r"\.\./[\w.-]+/|\.\./[\w-]+\.md|(?<![\w/])DESIGN\.md")


def tracked_text_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    return [ROOT / n for n in names if not n.endswith((".png", ".npz", ".npy"))]


def test_no_tracked_file_cites_a_path_outside_the_repository():
    cited = []
    for path in tracked_text_files():
        if path == Path(__file__) or not path.is_file():
            continue
        text = path.read_text(errors="replace")
        cited += [f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: "
                  f"{m.group()}" for m in OUTSIDE.finditer(text)]
    assert not cited, cited
    assert (ROOT / "docs" / "design.md").is_file()
