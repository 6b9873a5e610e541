"""polcam.camera.registry: device-id prefixes -> backends."""

from __future__ import annotations

import pytest

from polcam.camera import AravisCamera, ReplayCamera
from polcam.camera.base import CameraNotFoundError
from polcam.camera.registry import _BACKENDS, backends, open_camera, register_backend


def test_prefixes_pick_the_backend(tmp_path):
    assert set(backends()) == {"replay:", "*"}
    assert isinstance(open_camera(f"replay:{tmp_path}"), ReplayCamera)
    assert isinstance(open_camera("Fake_1"), AravisCamera)   # the default backend; nothing opened yet
    with pytest.raises(CameraNotFoundError, match="no camera id given"):
        open_camera("  ")


def test_a_registered_prefix_is_used():
    seen = {}

    def factory(rest, **options):
        seen.update(rest=rest, **options)
        return "camera"

    register_backend("probe:", factory)
    try:
        assert open_camera("probe:abc", queue_frames=3) == "camera"
        assert seen == {"rest": "abc", "queue_frames": 3}
    finally:
        del _BACKENDS["probe:"]
