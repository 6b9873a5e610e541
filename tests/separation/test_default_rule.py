"""The default-method rule: its steps on planted tables, and the registry against the recorded table."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from polcam.bench.default_rule import HIGHLIGHT_REFERENCE, pick, pick_all
from polcam.separation import default_method

TABLE = Path(__file__).with_name("default_rule_table.json")


def _row(kept_mean, kept_min, invented, spread, psnr):
    return {"matte_kept_min_mean": kept_mean, "matte_kept_min": kept_min, "invented_max": invented,
            "spread": spread, "validation_psnr": psnr}


def test_the_best_synthetic_mean_among_the_methods_that_do_no_harm():
    rows = {"a": _row(0.95, 0.90, 0.003, 0.03, 30.0),
            "b": _row(0.92, 0.86, 0.004, 0.02, 31.0),
            "c": _row(0.85, 0.70, 0.002, 0.01, 35.0),     # best synthetic, keeps too little
            "d": _row(0.95, 0.84, 0.002, 0.01, 34.0),     # one stack under 0.85
            "e": _row(0.97, 0.95, 0.050, 0.01, 33.0)}     # invents structure in clipped regions
    assert pick(rows)[0] == "b"
    rows["b"]["matte_kept_min_mean"] = 0.899
    assert pick(rows)[0] == "a"


def _sep(row, top, spread):
    return {**row, "top_removed": top, "spread": spread}


def test_a_default_must_separate_as_well_as_the_reference_baseline():
    """Step 3: keeping every surface is not enough; the highlights must go and the specular layer
    must have one colour, at least as well as the reference (wen21)."""
    ref = HIGHLIGHT_REFERENCE
    rows = {ref: _sep(_row(0.91, 0.89, 0.006, 0.016, 24.5), 0.096, 0.016),
            "polarized-only": _sep(_row(0.94, 0.92, 0.003, 0.244, 26.1), 0.044, 0.244),  # imin-like
            "thin": _sep(_row(0.99, 0.98, 0.002, 0.020, 29.0), 0.027, 0.020)}          # removes too little
    assert pick(rows)[0] == ref
    rows["better"] = _sep(_row(0.93, 0.90, 0.004, 0.012, 25.0), 0.120, 0.012)
    assert pick(rows)[0] == "better"
    rows["better"]["spread"] = 0.017                                                  # wider than the reference
    assert pick(rows)[0] == ref
    # without the reference's figures (mono) the step is skipped
    del rows[ref]
    assert pick(rows)[0] == "thin"


def test_if_none_passes_the_most_kept_among_narrow_spreads():
    rows = {"a": _row(0.80, 0.70, 0.003, 0.20, 30.0),     # keeps most, spread too wide
            "b": _row(0.78, 0.70, 0.003, 0.04, 31.0),
            "c": _row(0.74, 0.60, 0.003, 0.01, 35.0)}
    method, why = pick(rows)
    assert method == "b" and "no method passes" in why
    # a mono table with no real figures: the synthetic mean alone
    assert pick({"imin": {"validation_psnr": 30.0}, "x": {"validation_psnr": 30.5}})[0] == "x"
    with pytest.raises(ValueError):
        pick({})


def test_the_registry_default_is_the_one_the_rule_picks_from_the_recorded_table():
    table = json.loads(TABLE.read_text())
    chosen = pick_all(table)
    assert chosen == {"stack": default_method("stack"), "mono-stack": default_method("mono-stack")}
    # the recorded choice is the rule's on the recorded figures, and the commands are recorded
    assert table["picked"]["stack"][0] == chosen["stack"] and table["picked"]["mono-stack"][0] == chosen["mono-stack"]
    assert any("bench real --relit" in c for c in table["commands"])
    assert any("--split validation" in c for c in table["commands"])
