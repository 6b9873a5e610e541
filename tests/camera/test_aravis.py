"""Device discovery through the real Aravis stack (its in-process Fake camera)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from polcam.camera import aravis_available, list_devices
from polcam.errors import CameraUnavailableError

needs_aravis = pytest.mark.skipif(not aravis_available(), reason="Aravis 0.8 is not installed")


@needs_aravis
def test_fake_camera_is_listed():
    devices = list_devices(fake=True)
    fake = [d for d in devices if d.id == "Fake_1"]
    assert fake, devices
    assert fake[0].vendor == "Aravis" and fake[0].protocol == "Fake"


def test_missing_aravis_gives_install_instructions():
    # a fresh interpreter with Aravis disabled: polcam imports, the camera command explains itself
    code = (
        "import polcam, polcam.stokes\n"
        "from polcam.cli import main\n"
        "raise SystemExit(main(['devices']))\n"
    )
    env = {"POLCAM_NO_ARAVIS": "1", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 3
    assert "drivers/install.sh" in proc.stderr and "Aravis" in proc.stderr


def test_load_error_type(monkeypatch):
    import polcam.camera.aravis as arv

    monkeypatch.setattr(arv, "_ARAVIS", None)
    monkeypatch.setenv("POLCAM_NO_ARAVIS", "1")
    with pytest.raises(CameraUnavailableError, match="install"):
        arv.load_aravis()
