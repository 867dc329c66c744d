"""The diagnosis-sensitivity benchmark perturbs only the outputs, by the stated relative
amount, and reports every kind of change between runs."""

from __future__ import annotations

import numpy as np

from benchmarks.diagnosis_sensitivity import compare, perturbed


def test_only_the_outputs_move_and_by_the_relative_amount_drawn():
    data = {"u": np.ones((2, 3)), "y": np.full((2, 3), 4.0),
            "y_validation": np.full((2, 3), -2.0), "fs": np.array(8.0)}
    moved = perturbed(data, 1e-3, seed=5)
    assert moved["u"] is data["u"] and moved["fs"] is data["fs"]
    for key in ("y", "y_validation"):
        relative = moved[key] / data[key] - 1.0
        # six standard normal draws times 1e-3: not all zero, none beyond 6 sigma
        assert 0 < np.max(np.abs(relative)) < 6e-3
    np.testing.assert_array_equal(perturbed(data, 1e-3, seed=5)["y"], moved["y"])


def _run(order=10, nrmse=5.0, reduction=0.5, top3=("a", "b", "c"), proposal="p",
         claim="c"):
    return {"order": order, "nrmse_pct": nrmse, "locations": {"a": reduction, "b": 0.1},
            "top3": list(top3), "proposal": proposal, "claim": claim}


def test_every_change_between_runs_is_reported():
    same = compare([_run(), _run()])
    assert not any(same[k] for k in ("revision0", "top3", "proposal", "claim"))
    assert same["max_reduction_shift"] == 0.0
    changed = compare([_run(), _run(nrmse=5.1, reduction=0.4, top3=("b", "a", "c"),
                                    proposal="q", claim="nothing")])
    assert all(changed[k] for k in ("revision0", "top3", "proposal", "claim"))
    assert abs(changed["max_reduction_shift"] - 0.1) < 1e-12
