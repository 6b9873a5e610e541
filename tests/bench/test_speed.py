"""polcam bench speed: the rows it reports are consistent with one another (no timed assertions)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from polcam.bench.speed import SpeedRow, _full_frame_raw, format_markdown, measure, run
from polcam.cli import main


def test_run_pairs_exact_and_fast_on_the_same_input():
    rows = run(sizes=(24, 32), scenes=("Bunny4",), exact_max=24, frame=False, isolate=False,
               progress=False)
    assert [(r.case, r.solver) for r in rows] == [
        ("Bunny4 24x24", "exact"), ("Bunny4 24x24", "fast"), ("Bunny4 32x32", "fast")]
    exact, fast, alone = rows
    assert (exact.height, exact.width) == (24, 24) and exact.options == {"solver": "exact"}
    assert fast.speedup == pytest.approx(exact.seconds / fast.seconds)
    assert fast.psnr_delta == pytest.approx(fast.psnr - exact.psnr)
    # the two solvers give the same answer here (docs/benchmarks.md: within 0.1 dB at 256)
    assert abs(fast.psnr_delta) < 0.1 and fast.psnr_vs_exact > 50
    assert np.isnan(alone.speedup) and np.isnan(alone.psnr_delta)
    assert all(r.iterations > 0 and r.converged and r.tiles == 1 and r.peak_mb > 0 for r in rows)
    md = format_markdown(rows)
    assert md.count("\n") == 4 and "| Bunny4 24x24 | exact | 24 x 24 |" in md


def test_another_method_is_timed_alone(capsys):
    rows = run(sizes=(32,), scenes=("Bunny4",), frame=False, isolate=False, progress=False,
               method="polarized-residual")
    assert [(r.case, r.solver) for r in rows] == [("Bunny4 32x32", "polarized-residual")]
    r = rows[0]
    assert (r.height, r.width) == (32, 32) and r.seconds > 0 and r.options == {}
    # its diffuse is scored against the truth like the tensor solver's
    assert 15 < r.psnr < 80 and np.isnan(r.speedup)
    from polcam.errors import MethodError

    with pytest.raises(MethodError, match="no-such"):
        run(sizes=(32,), frame=False, isolate=False, progress=False, method="no-such")
    assert main(["bench", "speed", "--method", "imin", "--tol", "1e-3", "--no-frame", "--sizes", "16"]) == 2
    assert "tensor method's options" in capsys.readouterr().err
    assert main(["bench", "speed", "--method", "imin", "--device", "cpu", "--no-frame", "--sizes", "16"]) == 2
    assert "'imin' has no PyTorch backend" in capsys.readouterr().err


def test_polarized_residual_on_a_device():
    torch = pytest.importorskip("torch")
    dev = "cuda" if torch.cuda.is_available() else "cpu"
    (row,) = run(sizes=(32,), scenes=("Bunny4",), frame=False, isolate=False, progress=False,
                 method="polarized-residual", options={"device": dev})
    (ref,) = run(sizes=(32,), scenes=("Bunny4",), frame=False, isolate=False, progress=False,
                 method="polarized-residual")
    assert row.options == {"device": dev} and row.solver == "polarized-residual"
    assert row.device == (torch.cuda.get_device_name() if dev == "cuda" else "cpu")
    # the same layer on either backend
    assert row.psnr == pytest.approx(ref.psnr, abs=0.01)


def test_measure_reports_the_options_it_ran_with(tmp_path):
    got = measure({"kind": "scene", "scene": "Bunny1", "size": 24,
                   "options": {"solver": "fast", "tile": 12, "overlap": 0, "workers": 1},
                   "save": str(tmp_path / "d.npy")})
    assert got["tiles"] == 4 and (got["height"], got["width"]) == (24, 24)
    assert np.load(tmp_path / "d.npy").shape == (24, 24, 3)
    assert set(got["timings"]) >= {"init", "ialm"}


def test_main_runs_in_child_processes_and_writes_json(tmp_path, capsys):
    out = tmp_path / "rows.json"
    assert main(["bench", "speed", "--sizes", "24", "--exact-max", "0", "--no-frame", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["solver"] for r in rows] == ["fast"] and rows[0]["height"] == 24
    assert "| Bunny4 24x24 | fast |" in capsys.readouterr().out
    assert SpeedRow(**{**rows[0], "load": tuple(rows[0]["load"])}).case == "Bunny4 24x24"


@pytest.mark.slow
def test_full_frame_raw_is_a_sensor_frame():
    raw = _full_frame_raw("Bunny5", 0)
    assert raw.shape == (2048, 2448) and raw.dtype == np.float32
    assert 0 <= raw.min() and raw.max() <= 1


def test_device_rows_name_the_device():
    torch = pytest.importorskip("torch")
    dev = "cuda" if torch.cuda.is_available() else "cpu"
    rows = run(sizes=(24,), scenes=("Bunny4",), exact_max=0, frame=False, isolate=False, progress=False,
               options={"device": dev})
    (row,) = rows
    assert row.options == {"solver": "fast", "device": dev} and row.converged
    if dev == "cuda":
        assert row.device == torch.cuda.get_device_name() and row.device_peak_mb > 0
        assert "+ GPU" in format_markdown(rows)
    else:
        assert row.device == "cpu" and np.isnan(row.device_peak_mb)
        assert "+ GPU" not in format_markdown(rows)


def test_cuda_device_is_named_or_refused_clearly():
    """``--device cuda`` prints the GPU's model first; without one the command fails saying so."""
    import subprocess
    import sys

    try:
        import torch

        gpu = torch.cuda.is_available()
    except ImportError:
        gpu = False
    cmd = [sys.executable, "-m", "polcam", "bench", "speed", "--device", "cuda", "--sizes", "16",
           "--exact-max", "0", "--no-frame"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, check=False)
    if gpu:
        assert res.returncode == 0, res.stderr
        assert res.stdout.splitlines()[0] == f"device cuda: {torch.cuda.get_device_name()}"
    else:
        assert res.returncode != 0
        assert "no GPU available" in res.stderr or "no CUDA GPU available" in res.stderr, res.stderr
        assert "Traceback" not in res.stderr


def test_targets_table_says_which_targets_are_met():
    from polcam.bench.targets import TargetRow, format_markdown

    rows = [TargetRow("maps, mono: polcam bilinear vs polanalyser", 2.5, "x", 2.0),
            TargetRow("separation, wen21", 0.75, "s", 0.6)]
    assert [r.met for r in rows] == [True, False]
    table = format_markdown(rows)
    assert "| maps, mono: polcam bilinear vs polanalyser | 2.50x | >= 2x | yes |" in table
    assert "| separation, wen21 | 0.750 s | <= 0.6 s | no |" in table


@pytest.mark.slow
def test_targets_run_prints_every_figure(capsys):
    pytest.importorskip("polanalyser")
    assert main(["bench", "speed", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    for figure in ("maps, mono: polcam bilinear vs polanalyser", "maps, mono: polcam default (eari) vs polanalyser",
                   "maps, colour: polcam bilinear vs polanalyser",
                   "maps, colour: polcam default (lmmse) vs polanalyser",
                   "separation, wen21, 1224 x 1024 colour", "separation, colour default (wen21), 1224 x 1024",
                   "raw 2448 x 2048 colour -> maps and layers (wen21, cell)"):
        assert f"| {figure} |" in out, figure
