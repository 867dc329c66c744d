"""Study figures show failures: a revision or a candidate whose model could not be
simulated is drawn as a hatched "failed" bar, never left as an empty slot."""

from __future__ import annotations

import io

import numpy as np
from matplotlib.colors import to_rgb
from matplotlib.image import imread

from fnsi.diagnosis import Candidate, Diagnosis, Effect
from fnsi.study_plots import FAILED_STYLE, plot_candidates


def failed_share(png: bytes) -> float:
    """Share of the pixels painted in the failed bars' fill colour."""
    pixels = imread(io.BytesIO(png))[..., :3]
    return float(np.mean(np.all(np.abs(pixels - to_rgb(FAILED_STYLE["facecolor"])) < 0.02,
                                axis=-1)))


def candidate(nrmse: float, failure: str | None) -> Candidate:
    return Candidate(Effect.CUBIC_STIFFNESS, None, None, 10, nrmse, 2.0 / nrmse,
                     beats_noise_floor=False, screening_reduction=None, log10_real_imag=None,
                     flatness_percent=None, explanation="", failure=failure)


def diagnosis(*candidates: Candidate) -> Diagnosis:
    return Diagnosis(revision=0, nrmse_before_percent=2.0, noise_floor_percent=0.5,
                     candidates=candidates, locations=(), proposals=(), curves=(),
                     summary="", timings={})


def test_a_failed_candidate_is_drawn_as_failed():
    ok = plot_candidates(diagnosis(candidate(1.0, None), candidate(1.5, None)))
    failed = plot_candidates(diagnosis(candidate(1.0, None),
                                       candidate(float("inf"), "unstable model")))
    assert failed_share(ok) == 0
    assert failed_share(failed) > 0.02  # a bar across the chart, not a missing slot
    only_failures = plot_candidates(diagnosis(candidate(float("inf"), "unstable model")))
    assert failed_share(only_failures) > 0.02
