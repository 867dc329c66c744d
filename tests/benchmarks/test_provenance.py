"""Provenance of the generalisation benchmark's answers: the files drawn and the machine."""

from __future__ import annotations

import json

import numpy as np

from benchmarks.generalisation import hidden
from benchmarks.generalisation.blind import cases_dir
from benchmarks.generalisation.provenance import file_digest, machine, provenance_words


def _tiny_case(seed: np.random.SeedSequence, *, noise_free: bool = False):
    """Stands for :func:`hidden.draw_hidden_case`: a file whose bytes depend on the seed."""
    return ({"u": np.random.default_rng(seed).standard_normal(8)},
            {"plan": {"kinds": []}, "elements": []})


def _answers(root, cases) -> dict[str, dict]:
    """What the runner records beside each answer (``runner._answer_case``)."""
    return {case: {"provenance": {"digest": file_digest(cases_dir(root) / f"{case}.npz"),
                                  "machine": machine()}} for case in cases}


def test_the_index_holds_every_files_digest_and_the_report_names_a_changed_file(
        tmp_path, monkeypatch):
    monkeypatch.setattr(hidden, "draw_hidden_case", _tiny_case)  # the pool forks: it sees it
    drawn = hidden.generate_hidden(tmp_path, 3, 3, jobs=1)
    index = json.loads((cases_dir(tmp_path) / "index.json").read_text())
    assert sorted(index["digests"]) == drawn
    assert len(set(index["digests"].values())) == 3   # three different files
    words = provenance_words(index, _answers(tmp_path, drawn))
    assert words.startswith("Case files: the 3 answered are the ones drawn")
    assert f"numpy {np.__version__}" in words and "OPENBLAS_CORETYPE=" in words
    # one file rewritten after the draw (another machine's generator, say)
    np.savez(cases_dir(tmp_path) / "case0001.npz", u=np.zeros(8))
    words = provenance_words(index, _answers(tmp_path, drawn))
    assert words.startswith("Case files: 1 answered file(s) differ from the ones drawn: "
                            "case0001.")


def test_answers_recorded_before_digests_say_so():
    words = provenance_words({"cases": ["case0000"]}, {"case0000": {"status": "ok"}})
    assert words == ("Case files: no digests recorded (drawn or answered before digests "
                     "were kept).")
