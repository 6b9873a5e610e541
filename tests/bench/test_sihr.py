"""The SIHR fidelity benchmark: metrics, the reference table, run() and the Markdown table."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from polcam.bench import sihr
from polcam.errors import FrameReadError, MethodError
from polcam.separation import register, unregister


def test_psnr_matches_skimage():
    rng = np.random.default_rng(0)
    truth = rng.random((20, 30, 3))
    est = np.clip(truth + rng.normal(0, 0.05, truth.shape), 0, 1)
    assert sihr.psnr(est, truth) == pytest.approx(peak_signal_noise_ratio(truth, est, data_range=1.0), rel=1e-12)
    assert sihr.psnr(truth, truth) == float("inf")
    # the estimate is clipped to [0, 1] before scoring
    assert sihr.psnr(truth + 2.0, truth) == pytest.approx(sihr.psnr(np.ones_like(truth), truth))


def test_ssim_is_the_mean_of_per_channel_ssim():
    rng = np.random.default_rng(1)
    truth = rng.random((40, 50, 3))
    est = np.clip(truth + rng.normal(0, 0.1, truth.shape), 0, 1)
    per_channel = [
        structural_similarity(truth[..., c], est[..., c], data_range=1.0, gaussian_weights=True, sigma=1.5,
                              use_sample_covariance=False)
        for c in range(3)
    ]
    assert sihr.ssim(est, truth) == pytest.approx(np.mean(per_channel), rel=1e-12)
    assert sihr.ssim(truth, truth) == pytest.approx(1.0)


def test_mean_abs_deviation():
    assert sihr.mean_abs_deviation([36.0, 38.0, 36.2, 33.0], [36.5, 37.5, 36.2, 33.5]) == pytest.approx(0.375)
    with pytest.raises(ValueError):
        sihr.mean_abs_deviation([1.0, 2.0], [1.0, 2.0, 3.0])


def test_reference_table_matches_the_data_sources(shared_data):
    # the table kept in the module is the one the data folder quotes
    text = (shared_data / "shen2013" / "SOURCES.md").read_text()
    for method, values in sihr.REFERENCE_PSNR.items():
        name = {"tan05": "Tan05", "yoon06": "Yoon06", "shen08": "Shen08", "shen09": "Shen09",
                "yang10": "Yang10", "shen13": "Shen13", "akashi16": "Akashi16"}[method]
        line = next(ln for ln in text.splitlines() if ln.startswith(f"| {name}"))
        cells = [float(c) for c in line.strip("| \n").split("|")[1:]]
        assert tuple(cells) == values


def _write_dataset(folder: Path, rng: np.random.Generator, shape=(24, 32)) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Four 8-bit image pairs: a coloured diffuse layer and the same plus a white lobe."""
    folder.mkdir(parents=True, exist_ok=True)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    pairs = {}
    for name in sihr.IMAGES:
        diffuse = rng.uniform(0.1, 0.6, (1, 1, 3)) * (0.6 + 0.4 * rng.random((h, w, 1)))
        lobe = 0.3 * np.exp(-((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / 20.0)
        image = np.clip(diffuse + lobe[..., None], 0, 1)
        img8 = np.round(image * 255).astype(np.uint8)
        gt8 = np.round(diffuse * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{name}.png"), img8[..., ::-1])
        cv2.imwrite(str(folder / f"{name}_gt.png"), gt8[..., ::-1])
        pairs[name] = (img8 / 255.0, gt8 / 255.0)
    return pairs


@pytest.fixture
def identity_method():
    register("_toy_identity", kind="single")(lambda image: (image.copy(), {"note": 1}))
    yield "_toy_identity"
    unregister("_toy_identity")


def test_run_scores_against_the_ground_truth(tmp_path, identity_method):
    pairs = _write_dataset(tmp_path / "shen2013", np.random.default_rng(2))
    rows = sihr.run(tmp_path, [identity_method])  # the parent folder holding shen2013/ is accepted
    (row,) = rows
    assert row["method"] == identity_method
    for name, (image, truth) in pairs.items():
        # identity: the score is the input's own PSNR against the truth (RGB order kept)
        assert row["psnr"][name] == pytest.approx(peak_signal_noise_ratio(truth, image, data_range=1.0), rel=1e-6)
        assert 0 < row["ssim"][name] <= 1
        assert row["seconds"][name] >= 0
        assert row["info"][name] == {"note": 1}
    assert row["mean_psnr"] == pytest.approx(np.mean(list(row["psnr"].values())))
    assert row["reference_psnr"] is None and row["deviation"] is None
    assert row["seconds_640x480"] is None  # the toy images are not 640 x 480


def test_run_reference_and_deviation(tmp_path):
    _write_dataset(tmp_path, np.random.default_rng(3))
    (row,) = sihr.run(tmp_path, ["shen13"])
    ref = sihr.REFERENCE_PSNR["shen13"]
    assert row["reference_psnr"] == dict(zip(sihr.IMAGES, ref))
    expected = np.mean([abs(row["psnr"][n] - r) for n, r in zip(sihr.IMAGES, ref)])
    assert row["deviation"] == pytest.approx(expected)
    assert row["reference_seconds"] == sihr.REFERENCE_SECONDS["shen13"]


def test_default_methods_are_the_registered_ones():
    from polcam.separation import methods

    names = sihr.default_methods()
    registered = set(methods())
    assert set(names) <= registered
    assert {m for m in sihr.REFERENCE_PSNR if m in registered} <= set(names)
    assert {"yang10", "shen09", "shen13", "yamamoto19"} <= set(names)
    assert "imin" not in names


def test_run_refuses_unknown_and_stack_methods(tmp_path):
    _write_dataset(tmp_path, np.random.default_rng(4))
    with pytest.raises(MethodError, match="unknown"):
        sihr.run(tmp_path, ["no-such-method"])
    with pytest.raises(MethodError, match="single-image"):
        sihr.run(tmp_path, ["imin"])


def test_missing_or_bad_files(tmp_path):
    _write_dataset(tmp_path, np.random.default_rng(5))
    (tmp_path / "masks_gt.png").unlink()
    with pytest.raises(FrameReadError, match="masks_gt.png"):
        sihr.run(tmp_path, ["shen09"])
    cv2.imwrite(str(tmp_path / "masks_gt.png"), np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(FrameReadError, match="equal shapes"):
        sihr.load_pair(tmp_path, "masks")
    (tmp_path / "cups.png").write_bytes(b"not a png")
    with pytest.raises(FrameReadError, match="cups.png"):
        sihr.load_pair(tmp_path, "cups")


def test_format_table():
    row = {
        "method": "yang10",
        "psnr": dict(zip(sihr.IMAGES, (36.91, 37.81, 36.66, 32.74))),
        "ssim": dict(zip(sihr.IMAGES, (0.947, 0.95, 0.955, 0.908))),
        "mean_psnr": 36.03, "mean_ssim": 0.94, "mean_seconds": 0.2, "seconds_640x480": 0.31,
        "reference_psnr": dict(zip(sihr.IMAGES, sihr.REFERENCE_PSNR["yang10"])),
        "reference_ssim": dict(zip(sihr.IMAGES, sihr.REFERENCE_SSIM["yang10"])),
        "reference_seconds": 0.16, "deviation": 0.4875,
    }
    extra = dict(row, method="yamamoto19", reference_psnr=None, reference_ssim=None,
                 reference_seconds=None, deviation=None, seconds_640x480=None)
    text = sihr.format_table([row, extra])
    lines = text.splitlines()
    psnr_line = next(ln for ln in lines if ln.startswith("| yang10 | 36.91"))
    assert "| 36.03 | 36.5 / 37.5 / 36.2 / 33.5 | 0.49 |" in psnr_line
    assert any(ln.startswith("| yamamoto19 | 36.91") and ln.endswith("| - | - |") for ln in lines)
    assert "| yang10 | 0.200 | 0.310 | 0.16 |" in lines
    assert "| yamamoto19 | 0.200 | - | - |" in lines
    assert "SSIM" in text and "volumetric" in text


def test_main(tmp_path, capsys):
    from polcam.cli import main

    _write_dataset(tmp_path, np.random.default_rng(6))
    assert main(["bench", "sihr", "--data", str(tmp_path), "--methods", "shen09,shen13"]) == 0
    out = capsys.readouterr().out
    assert "| shen09 |" in out and "| shen13 |" in out and "| yang10 |" not in out
    assert main(["bench", "sihr", "--data", str(tmp_path / "nowhere"), "--methods", "shen09"]) == 2
    assert "animals.png" in capsys.readouterr().err


@pytest.mark.slow
def test_fidelity_of_the_implemented_methods(shared_data):
    rows = {r["method"]: r for r in sihr.run(shared_data, ["shen09", "yang10", "shen13", "yamamoto19"])}
    for m in ("shen09", "yang10", "shen13"):
        assert rows[m]["deviation"] < 1.0, (m, rows[m]["psnr"])
    assert rows["yamamoto19"]["reference_psnr"] is None
    assert rows["yang10"]["seconds_640x480"] is not None
