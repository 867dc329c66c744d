"""The blind protocol: where each phase reads and writes, and what it may not open.

Layout of a benchmark directory::

    cases/index.json      seed, count, case ids (phase 1)
    cases/<id>.npz        what a user would have: forces, responses, fs, periods,
                          quantity, channel names and the excitation band (phase 1)
    sealed/truth.json     the structures and their modes (phase 1; read in phase 3 only)
    answers/<id>.json     the library's answer for each case (phase 2)

Phase 2 runs under :func:`blindfold`: an audit hook refuses every ``open`` of a path
under ``sealed/`` while it is active, so the runner cannot read the truth even by
mistake. Phase 3 (:func:`require_answers`) refuses to start until every case has its
answer on disk.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from collections.abc import Iterator
from pathlib import Path

_BLINDFOLDED: set[str] = set()
_HOOKED = False


def cases_dir(root: Path) -> Path:
    """Directory of the case data (phase 1's public output)."""
    return Path(root) / "cases"


def truth_path(root: Path) -> Path:
    """The sealed truth file."""
    return Path(root) / "sealed" / "truth.json"


def answer_path(root: Path, case: str) -> Path:
    """Where phase 2 writes the answer of ``case``."""
    return Path(root) / "answers" / f"{case}.json"


def fresh_cases_dir(root: Path) -> Path:
    """The case directory of ``root``, created; ValueError when it already holds cases
    (phase 1 never overwrites a benchmark)."""
    directory = cases_dir(root)
    if (directory / "index.json").exists():
        raise ValueError(f"{directory} already holds cases; use a fresh directory")
    directory.mkdir(parents=True, exist_ok=True)
    return directory


def read_index(root: Path) -> dict:
    """Phase 1's index {"seed", "count", "cases"}; ValueError when phase 1 has not run."""
    path = cases_dir(root) / "index.json"
    if not path.is_file():
        raise ValueError(f"no cases in {root}: run the generation phase first")
    return json.loads(path.read_text())


def _audit(event: str, args: tuple) -> None:
    if event != "open" or not _BLINDFOLDED or isinstance(args[0], int):
        return
    path = os.path.abspath(os.fsdecode(args[0]))
    for sealed in _BLINDFOLDED:
        if path == sealed or path.startswith(sealed + os.sep):
            raise PermissionError(f"blind phase: {path} is sealed until every answer is "
                                  "recorded")


@contextlib.contextmanager
def blindfold(root: Path) -> Iterator[None]:
    """Refuse to open anything under ``root``/sealed inside the block (phase 2)."""
    global _HOOKED
    if not _HOOKED:  # audit hooks cannot be removed: install one, switch it by the set
        sys.addaudithook(_audit)
        _HOOKED = True
    sealed = os.path.abspath(truth_path(root).parent)
    _BLINDFOLDED.add(sealed)
    try:
        yield
    finally:
        _BLINDFOLDED.discard(sealed)


def require_answers(root: Path) -> list[str]:
    """Case ids, after checking that every case has an answer (phase 3's precondition).

    Raises
    ------
    ValueError
        Listing the cases still without an answer.
    """
    cases = read_index(root)["cases"]
    missing = [c for c in cases if not answer_path(root, c).is_file()]
    if missing:
        raise ValueError(f"{len(missing)} of {len(cases)} cases have no answer yet (first: "
                         f"{missing[:3]}); run the identification phase before scoring")
    return cases


def read_answers(root: Path, cases: list[str]) -> dict[str, dict]:
    """The recorded answers of ``cases`` (phase 2's output), by case id."""
    return {case: json.loads(answer_path(root, case).read_text()) for case in cases}


def write_json(path: Path, value: dict) -> None:
    """Write ``value`` as JSON, creating the directory; atomic (a partial answer never
    counts as recorded)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    partial.write_text(json.dumps(value, indent=1))
    partial.replace(path)
