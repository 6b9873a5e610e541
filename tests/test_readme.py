"""README's "Using it from Python" example runs as written: as a script file (it has no
``if __name__ == "__main__":`` guard) and piped to ``python -``, from a copy of the repository's
fixtures, with exit status 0, nothing on stderr, and the images it says it writes."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def _example() -> str:
    text = (REPO / "README.md").read_text()
    section = text[text.index("### Using it from Python"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture
def workdir(tmp_path: Path) -> Path:
    shutil.copytree(REPO / "fixtures" / "raw", tmp_path / "fixtures" / "raw")
    return tmp_path


def _check(proc: subprocess.CompletedProcess, workdir: Path) -> None:
    from polcam.io import read_image

    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    method, *_ = proc.stdout.split()
    from polcam.separation import default_method

    assert method == default_method("stack")
    images = {n: read_image(workdir / "python-output" / f"{n}.exr")[0] for n in ("dolp", "aolp", "diffuse", "specular")}
    assert all(im.shape == (128, 128, 3) and np.all(np.isfinite(im)) for im in images.values())
    assert 0 <= images["dolp"].min() and images["dolp"].max() <= 1
    assert 0 <= images["aolp"].min() and images["aolp"].max() < np.pi


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONWARNINGS": "default"}


def test_readme_example_as_a_script_file(workdir: Path):
    (workdir / "example.py").write_text(_example())
    _check(subprocess.run([sys.executable, "example.py"], cwd=workdir, capture_output=True, text=True,
                          env=_env(), timeout=300), workdir)


def test_readme_example_through_stdin(workdir: Path):
    _check(subprocess.run([sys.executable, "-"], input=_example(), cwd=workdir, capture_output=True, text=True,
                          env=_env(), timeout=300), workdir)
