"""How polcam is installed: a script anywhere imports the installed package.

``make setup`` installs polcam editable with the checkout's root as a real ``sys.path`` entry
(``package-dir = {"" = "."}`` in pyproject.toml gives setuptools' static ``.pth``).  setuptools'
default for a flat layout is an import hook that runs after the path search, so a script in the
folder that holds the checkout (a ``polcam/`` folder without ``__init__.py`` on its ``sys.path``)
imported that folder as an empty namespace package.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_a_script_beside_a_polcam_folder_imports_the_package(tmp_path: Path):
    """The user's case, with this environment's polcam (the install under ``make test``)."""
    (tmp_path / "polcam").mkdir()                     # the checkout's folder, as seen from its parent
    (tmp_path / "polcam" / "README.md").write_text("not a package\n")
    script = tmp_path / "script.py"
    script.write_text("import polcam\nprint(polcam.__file__)\nprint(callable(polcam.read_frame))\n")
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    where, has = proc.stdout.split()
    assert has == "True" and Path(where).name == "__init__.py"
    assert Path(where).resolve().parent.parent != tmp_path.resolve()


def test_the_editable_install_is_a_path_entry():
    """The mechanism: setuptools writes a static .pth of the project root for this mapping."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert config["tool"]["setuptools"]["package-dir"] == {"": "."}
    assert config["tool"]["setuptools"]["packages"]["find"]["include"] == ["polcam*"]
