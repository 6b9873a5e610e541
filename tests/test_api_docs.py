"""The API reference (docs/reference/api) builds from the docstrings with Sphinx and numpydoc,
warnings as errors, and documents every name of the public modules' ``__all__``."""

from __future__ import annotations

import html
import importlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
API = REPO / "docs" / "reference" / "api"


def _modules() -> list[str]:
    text = (API / "conf.py").read_text()
    block = re.search(r"MODULES = \[(.*?)\]", text, re.S).group(1)
    return re.findall(r'"([a-z_.]+)"', block)


def test_the_api_reference_builds_without_warnings(tmp_path: Path):
    src = tmp_path / "src"
    shutil.copytree(API, src, ignore=shutil.ignore_patterns("generated", "_build"))
    out = tmp_path / "html"
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           str(src), str(out)], capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    assert "WARNING" not in proc.stderr and "ERROR" not in proc.stderr, proc.stderr

    modules = _modules()
    assert {"polcam", "polcam.io", "polcam.separation", "polcam.camera"} <= set(modules)
    index = (out / "index.html").read_text()
    for modname in modules:
        page = out / "generated" / f"{modname}.html"
        assert f"generated/{modname}.html" in index, modname
        text = html.unescape(re.sub(r"<[^>]+>", "", page.read_text()))
        for name in importlib.import_module(modname).__all__:
            if name.startswith("__"):
                continue
            # each name has its own entry: its signature or its value, with the module's prefix
            assert f"{modname}.{name}" in text, f"{modname}.{name} is not documented"
    separate = html.unescape(re.sub(r"<[^>]+>", "", (out / "generated" / "polcam.html").read_text()))
    # numpydoc rendered the sections of a docstring, and the doctested examples are shown
    assert "Parameters:" in separate and "Returns:" in separate and "Examples" in separate
