"""polcam process: outputs, resume, bad inputs, write failures, workers and Dask, Rerun."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from polcam.cli import main
from polcam.errors import FrameWriteError
from polcam.io import read_frame, read_image, write_frame
from polcam.process import OUTPUTS, ProcessOptions, plan, process_frame, run
from polcam.separation import default_method

MONO = "fruits_crop"
COLOUR = "synthetic_bunny5"


def _copy_fixture(fixtures_dir: Path, stem: str, dst: Path, new_stem: str | None = None) -> Path:
    new_stem = new_stem or stem
    for ext in (".png", ".json"):
        shutil.copy(fixtures_dir / "raw" / f"{stem}{ext}", dst / f"{new_stem}{ext}")
    return dst / f"{new_stem}.png"


def _small_colour(fixtures_dir: Path, dst: Path, name: str, offset: int = 0) -> Path:
    """A 64x64 crop of the colour fixture (offset keeps the 4-pixel period) as a 12-bit .npy + sidecar."""
    f = read_frame(fixtures_dir / "raw" / f"{COLOUR}.png")
    crop = f.mosaic[64 + offset:128 + offset, 64:128].copy()
    f.mosaic = crop
    f.metadata = {k: v for k, v in f.metadata.items() if k not in ("width", "height")}
    return write_frame(dst / f"{name}.npy", f)


@pytest.fixture
def raw_dir(tmp_path, fixtures_dir):
    d = tmp_path / "raw"
    d.mkdir()
    _copy_fixture(fixtures_dir, MONO, d)
    for i in range(2):
        _small_colour(fixtures_dir, d, f"colour{i}", offset=4 * i)
    return d


@pytest.mark.parametrize("args,match", [
    (["--method", "tensor", "--option", "max_itre=5"], "takes no option 'max_itre'"),
    (["--method", "yang10", "--option", "n4=3"], "method 'yang10' takes no option 'n4'"),
    (["--method", "tensr"], "separation method 'tensr' is unknown"),
])
def test_bad_method_or_option_is_refused_before_any_work(raw_dir, tmp_path, capsys, args, match):
    out = tmp_path / "out"
    assert main(["process", str(raw_dir), "-o", str(out), "--quiet", *args]) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()


def test_outputs_meta_and_summary(raw_dir, tmp_path):
    out = tmp_path / "out"
    assert main(["process", str(raw_dir), "-o", str(out), "--quiet", "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["done"] == 3 and summary["failed"] == []
    meta = json.loads((out / MONO / "meta.json").read_text())
    assert meta["method"] == default_method("mono-stack") and meta["layout"] == "imx250mzr"
    assert json.loads((out / "colour0" / "meta.json").read_text())["method"] == default_method("stack")
    import hashlib

    assert meta["input_sha256"] == hashlib.sha256((raw_dir / f"{MONO}.png").read_bytes()).hexdigest()
    for key in ("fingerprint", "fingerprint_parts", "polcam_version", "timings", "options_requested",
                "calibration_sha256", "separation_info"):
        assert key in meta
    # the fingerprint is the hash of the canonical JSON of its parts
    canon = json.dumps(meta["fingerprint_parts"], sort_keys=True, separators=(",", ":"))
    assert meta["fingerprint"] == hashlib.sha256(canon.encode()).hexdigest()
    d, _ = read_image(out / MONO / "diffuse.exr")
    s, _ = read_image(out / MONO / "specular.exr")
    s0, _ = read_image(out / MONO / "s0.exr")
    dolp, _ = read_image(out / MONO / "dolp.exr")
    aolp, _ = read_image(out / MONO / "aolp.exr")
    assert d.shape[:2] == (256, 320)                                             # cell resolution
    np.testing.assert_allclose((d + s)[..., 0], np.clip(s0[..., 0] / 2, None, None), atol=2e-3)
    assert dolp.min() >= 0 and dolp.max() <= 1 and aolp.min() >= 0 and aolp.max() < np.pi


def test_resume_skips_only_what_is_up_to_date(raw_dir, tmp_path):
    out = tmp_path / "out"
    opts = ["--quiet", "--workers", "1"]
    assert main(["process", str(raw_dir), "-o", str(out), *opts]) == 0
    stamp = (out / MONO / "diffuse.exr").stat().st_mtime_ns
    assert main(["process", str(raw_dir), "-o", str(out), *opts]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped"] == 3 and summary["done"] == 0
    assert (out / MONO / "diffuse.exr").stat().st_mtime_ns == stamp
    # a missing output, a changed option, or --force redo the frame
    (out / "colour1" / "aolp.exr").unlink()
    assert main(["process", str(raw_dir), "-o", str(out), *opts]) == 0
    assert json.loads((out / "summary.json").read_text())["done"] == 1
    # another method, then another option of it, on the colour frames: each redoes them
    colour = [str(raw_dir / "colour0.npy"), str(raw_dir / "colour1.npy")]
    tensor = ["--quiet", "--workers", "1", "--method", "tensor"]
    for option, done in (("max_iter=5", 2), ("max_iter=5", 0), ("max_iter=6", 2)):
        assert main(["process", *colour, "-o", str(out), *tensor, "--option", option]) == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["done"] == done and summary["skipped"] == 2 - done


def test_bad_inputs_are_reported_and_the_rest_finish(raw_dir, tmp_path, capsys):
    (raw_dir / "empty.png").write_bytes(b"")
    (raw_dir / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(200))
    good = (raw_dir / f"{MONO}.png").read_bytes()
    (raw_dir / "truncated.png").write_bytes(good[: len(good) // 2])
    (raw_dir / "wrongsize.raw").write_bytes(bytes(1000))
    (raw_dir / "wrongsize.json").write_text(json.dumps({"width": 64, "height": 64, "layout": "imx250mzr",
                                                       "pixel_format": "Mono8"}))
    np.save(raw_dir / "odd.npy", np.zeros((33, 64), np.uint16))
    out = tmp_path / "out"
    code = main(["process", str(raw_dir), "-o", str(out), "--quiet", "--workers", "1",
                 "--layout", "imx250mzr", "--method", "imin"])
    err = capsys.readouterr().err
    assert code == 1
    summary = json.loads((out / "summary.json").read_text())
    failed = {Path(f["input"]).name: f["error"] for f in summary["failed"]}
    assert set(failed) == {"empty.png", "garbage.png", "truncated.png", "wrongsize.raw", "odd.npy"}
    for name in failed:
        assert name in err
    assert "1000" in failed["wrongsize.raw"] and "odd" in failed["odd.npy"].lower()
    assert summary["done"] == 3                      # the good frames all finished
    for name in (MONO, "colour0", "colour1"):
        assert (out / name / "meta.json").is_file()


def test_mono_frames_refuse_colour_methods(raw_dir, tmp_path):
    jobs, _ = plan([raw_dir / f"{MONO}.png"], tmp_path / "o")
    r = process_frame(jobs[0], ProcessOptions(method="yang10"))
    assert r["status"] == "failed" and "needs colour" in r["error"] and MONO in r["error"]


def test_write_failure_loses_no_finished_frame(raw_dir, tmp_path, monkeypatch):
    import polcam.io

    real = polcam.io.write_image
    calls = {"n": 0}

    def flaky(path, *a, **k):
        if Path(path).parent.name == "colour0":
            raise FrameWriteError(f"cannot write: {os.strerror(errno.ENOSPC)}", path=path)
        calls["n"] += 1
        return real(path, *a, **k)

    monkeypatch.setattr(polcam.io, "write_image", flaky)
    jobs, _ = plan([raw_dir], tmp_path / "out")
    results = {r["name"]: r for r in run(jobs, ProcessOptions())}
    assert results["colour0"]["status"] == "failed" and "No space left" in results["colour0"]["error"]
    assert results["colour1"]["status"] == "done" and results[MONO]["status"] == "done"
    assert not (tmp_path / "out" / "colour0" / "meta.json").exists()
    for name in ("colour1", MONO):
        for p in OUTPUTS:
            read_image(tmp_path / "out" / name / f"{p}.exr")       # complete and readable


def test_unwritable_output_folder(raw_dir, tmp_path):
    blocker = tmp_path / "out"
    blocker.write_text("a file where the output folder should be")
    assert main(["process", str(raw_dir), "-o", str(blocker), "--quiet"]) == 2


def test_workers_and_dask_give_the_same_outputs(raw_dir, tmp_path):
    opts = ProcessOptions(method="tensor", method_options={"max_iter": 8})
    colour = [raw_dir / "colour0.npy", raw_dir / "colour1.npy"]
    outs = {}
    for label, kw in (("w1", {"workers": 1}), ("w2", {"workers": 2})):
        jobs, _ = plan(colour, tmp_path / label)
        assert all(r["status"] == "done" for r in run(jobs, opts, **kw))
        outs[label] = tmp_path / label
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        jobs, _ = plan(colour, tmp_path / "dask")
        assert all(r["status"] == "done" for r in run(jobs, opts, scheduler=client))
    outs["dask"] = tmp_path / "dask"
    for label, want in (("w1", None), ("w2", 1)):
        # in a pool of frame workers the tensor method starts no worker processes of its own;
        # what was asked for (the fingerprint) does not record that
        meta = json.loads((outs[label] / "colour0" / "meta.json").read_text())
        assert "workers" not in meta["method_options"]
        assert meta["separation_info"]["options"]["workers"] == want
    for name in ("colour0", "colour1"):
        for p in OUTPUTS:
            ref, _ = read_image(outs["w1"] / name / f"{p}.exr")
            for label in ("w2", "dask"):
                other, _ = read_image(outs[label] / name / f"{p}.exr")
                np.testing.assert_allclose(other, ref, atol=1e-6, rtol=0)           # tensor: within 1e-6


def _frames_for_kill(fixtures_dir: Path, d: Path, n: int) -> None:
    for i in range(n):
        _small_colour(fixtures_dir, d, f"f{i:02d}", offset=4 * (i % 8))


def _start(raw: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "polcam", "process", str(raw), "-o", str(out), "--json", "--workers", "1",
         "--method", "tensor", "--option", "max_iter=40"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_first_frame(proc: subprocess.Popen, timeout: float = 120) -> None:
    t0 = time.monotonic()
    assert proc.stdout is not None
    while time.monotonic() - t0 < timeout:
        line = proc.stdout.readline()
        if line and json.loads(line).get("event") == "frame":
            return
    raise AssertionError("no frame finished in time")


def _check_complete(out: Path, names: list[str]) -> None:
    for name in names:
        folder = out / name
        assert (folder / "meta.json").is_file(), name
        for p in OUTPUTS:
            read_image(folder / f"{p}.exr")
        assert not [f for f in folder.iterdir() if ".tmp" in f.name], name


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_interrupted_run_resumes_with_every_frame_done_once(fixtures_dir, tmp_path, sig):
    raw = tmp_path / "raw"
    raw.mkdir()
    _frames_for_kill(fixtures_dir, raw, 6)
    out = tmp_path / "out"
    proc = _start(raw, out)
    _wait_first_frame(proc)
    proc.send_signal(sig)
    proc.communicate(timeout=120)
    finished = sorted(p.parent.name for p in out.glob("*/meta.json"))
    assert 1 <= len(finished) < 6
    if sig == signal.SIGTERM:
        assert proc.returncode == 143          # 128 + SIGTERM, as a shell reports it
        summary = json.loads((out / "summary.json").read_text())
        assert summary["interrupted"] is True
        assert sorted(r["name"] for r in summary["results"] if r["status"] == "done") == finished
    # rerun: the finished frames are skipped, the others done, nothing partial is left
    assert main(["process", str(raw), "-o", str(out), "--quiet", "--workers", "1",
                 "--method", "tensor", "--option", "max_iter=40"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped"] == len(finished) and summary["done"] == 6 - len(finished)
    _check_complete(out, [f"f{i:02d}" for i in range(6)])


def test_rerun_recording_and_json_lines(raw_dir, tmp_path, capsys):
    out = tmp_path / "out"
    rrd = tmp_path / "run.rrd"
    assert main(["process", str(raw_dir), "-o", str(out), "--json", "--workers", "1",
                 "--rerun", str(rrd)]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [x["event"] for x in lines] == ["frame", "frame", "frame", "summary"]
    assert lines[-1]["done"] == 3
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.is_static:  # the colour maps' palettes, logged once per recording
            continue
        counts[str(chunk.entity_path)] = counts.get(str(chunk.entity_path), 0) + chunk.num_rows
    for entity in ("/polarization/s0", "/polarization/dolp", "/polarization/aolp", "/layers/diffuse",
                   "/layers/specular"):
        assert counts.get(entity) == 3, (entity, counts)


def test_recursive_names_keep_the_folder(fixtures_dir, tmp_path):
    raw = tmp_path / "raw"
    for sub in ("a", "b"):
        (raw / sub).mkdir(parents=True)
        _copy_fixture(fixtures_dir, MONO, raw / sub)
    jobs, problems = plan([raw], tmp_path / "out", recursive=True)
    assert [j.name for j in jobs] == [f"a/{MONO}", f"b/{MONO}"] and problems == []
    flat = tmp_path / "flat"
    flat.mkdir()
    _copy_fixture(fixtures_dir, MONO, flat)
    np.save(flat / f"{MONO}.npy", np.zeros((8, 8), np.uint8))
    jobs, problems = plan([flat], tmp_path / "out")
    assert len(jobs) == 1 and "already used" in problems[0]["error"]


def test_force_redoes_everything(raw_dir, tmp_path):
    out = tmp_path / "out"
    opts = ["--quiet", "--workers", "1"]
    assert main(["process", str(raw_dir), "-o", str(out), *opts]) == 0
    assert main(["process", str(raw_dir), "-o", str(out), *opts, "--force"]) == 0
    assert json.loads((out / "summary.json").read_text())["done"] == 3


@pytest.fixture
def tiny_disk(tmp_path):
    """A 512 KiB tmpfs (needs root and mount; skipped elsewhere)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_full_disk_is_reported_and_finished_frames_survive(fixtures_dir, tmp_path, tiny_disk, capsys):
    raw = tmp_path / "raw"
    raw.mkdir()
    for i in range(40):
        _small_colour(fixtures_dir, raw, f"f{i:02d}", offset=4 * (i % 8))
    out = tiny_disk / "out"
    code = main(["process", str(raw), "-o", str(out), "--quiet", "--workers", "1", "--method", "imin"])
    assert code == 1
    summary_path = out / "summary.json"
    finished = sorted(p.parent.name for p in out.glob("*/meta.json"))
    assert finished, "some frames fit on the disk"
    _check_complete(out, finished)                       # every finished frame is whole
    # the summary may not fit either; when it did, it names the failures
    if summary_path.exists():
        failed = json.loads(summary_path.read_text())["failed"]
        assert failed and all("No space left" in f["error"] for f in failed)
    assert len(finished) < 40
    err = capsys.readouterr().err
    assert "No space left on device" in err


def test_read_only_output_folder(raw_dir, tmp_path, tiny_disk, capsys):
    out = tiny_disk / "out"
    out.mkdir()
    subprocess.run(["mount", "-o", "remount,ro", str(tiny_disk)], check=True, capture_output=True)
    code = main(["process", str(raw_dir), "-o", str(out), "--quiet", "--workers", "1", "--method", "imin"])
    err = capsys.readouterr().err
    assert code != 0
    assert "Read-only file system" in err


def test_real_imx250mzr_frames_end_to_end(shared_data, tmp_path):
    out = tmp_path / "out"
    assert main(["process", str(shared_data / "real-imx250mzr"), "-o", str(out), "--layout", "imx250mzr",
                 "--quiet", "--workers", "1"]) == 0
    for name in ("fruits", "carps"):
        meta = json.loads((out / name / "meta.json").read_text())
        assert meta["method"] == default_method("mono-stack") and meta["shape"] == [4, 1024, 1224]
        d, _ = read_image(out / name / "diffuse.exr")
        s, _ = read_image(out / name / "specular.exr")
        assert d.shape[:2] == (1024, 1224) and d.min() >= 0 and s.min() >= -1e-6
    # the water reflection of "carps" is strongly polarized: imin removes much more there
    spec = {n: float(read_image(out / n / "specular.exr")[0].mean()) for n in ("fruits", "carps")}
    assert spec["carps"] > 2 * spec["fruits"]


def test_unreadable_input_is_reported(raw_dir, tmp_path, monkeypatch):
    """Root reads any file, so a permission error is injected where the input is opened."""
    import polcam.process as proc

    real = proc.sha256_file

    def denied(path):
        if Path(path).name == "colour1.npy":
            raise PermissionError(13, "Permission denied", str(path))
        return real(path)

    monkeypatch.setattr(proc, "sha256_file", denied)
    jobs, _ = plan([raw_dir], tmp_path / "out")
    results = {r["name"]: r for r in run(jobs, ProcessOptions(method="imin"))}
    assert results["colour1"]["status"] == "failed"
    assert "Permission denied" in results["colour1"]["error"] and "colour1.npy" in results["colour1"]["error"]
    assert results["colour0"]["status"] == "done" and results[MONO]["status"] == "done"


def test_calibration_is_applied_and_recorded(raw_dir, tmp_path, fixtures_dir):
    """A dark calibration of the mono frame's sensor: applied, hashed into the fingerprint; a
    calibration of another size is refused for that frame only."""
    from polcam.calibration import calibrate_dark, save_calibration

    rng = np.random.default_rng(0)
    darks = rng.poisson(6.0, (8, 512, 640)).astype(np.uint8)
    cal = save_calibration(tmp_path / "dark.npz", calibrate_dark(darks, layout="imx250mzr"))
    out = tmp_path / "out"
    code = main(["process", str(raw_dir), "-o", str(out), "--quiet", "--workers", "1",
                 "--method", "imin", "--calibration", str(cal)])
    assert code == 1                                        # the 64x64 colour frames do not match
    summary = json.loads((out / "summary.json").read_text())
    assert {Path(f["input"]).name for f in summary["failed"]} == {"colour0.npy", "colour1.npy"}
    meta = json.loads((out / MONO / "meta.json").read_text())
    import hashlib

    assert meta["calibration_sha256"] == hashlib.sha256(cal.read_bytes()).hexdigest()
    calibrated, _ = read_image(out / MONO / "s0.exr")
    plain = tmp_path / "plain"
    assert main(["process", str(raw_dir / f"{MONO}.png"), "-o", str(plain), "--quiet",
                 "--method", "imin"]) == 0
    uncal, _ = read_image(plain / MONO / "s0.exr")
    # the dark (about 6 counts of 255 per pixel) is subtracted: S0 = sum of four pixels / 2 drops by ~12/255
    assert 0.03 < float(np.mean(uncal - calibrated)) < 0.065
