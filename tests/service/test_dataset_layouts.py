"""Uploads of every layout case of issue 22: what each reader recognises (units, time
columns, MATLAB spellings, HDF5 groups), refuses (FRFs, mixed quantities) or hints
(transposed records, several groups). The same cases run through the CLI in
tests/fnsi/test_cli.py."""

from __future__ import annotations

import pytest

from tests.service import formats
from tests.service.test_datasets import upload


def units_of(summary: dict) -> dict[str, str | None]:
    return {c["name"]: c["unit"] for c in summary["channels"]}


@pytest.mark.parametrize("case", list(formats.LAYOUTS))
def test_each_layout_is_read_or_refused_with_what_to_change(client, tmp_path, case):
    layout = formats.LAYOUTS[case]
    response = upload(client, layout.write(tmp_path), layout.options or None)
    assert response.status_code == layout.status, response.text
    if layout.status != 201:
        detail = response.json()["detail"].lower()
        assert all(word in detail for word in layout.says), detail
        return
    body = response.json()
    for field, value in layout.fields.items():
        assert (units_of(body) if field == "units" else body[field]) == value, field


def test_channels_carry_their_quantity_and_unit(client, tmp_path):
    layout = formats.LAYOUTS["uff-unit-labels"]
    body = upload(client, layout.write(tmp_path), layout.options).json()
    assert [(c["name"], c["quantity"], c["unit"]) for c in body["channels"]] == [
        ("force", "force", "N"), ("NC2w_Z", "displacement", "mm"),
        ("NC2b_Z", "displacement", "mm")]
