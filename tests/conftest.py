"""Shared test fixtures.

``shared_data`` is the project's read-only data folder (``../shared/data`` beside the
repository, or ``$POLCAM_SHARED_DATA``); tests that need it skip cleanly where it is absent.
``dev`` runs a test once per PyTorch device (``cpu``, and ``cuda`` where there is one, or the
comma-separated ``$POLCAM_TEST_DEVICES``); without PyTorch the test is skipped, saying so.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("POLCAM_SHARED_DATA", REPO.parent / "shared" / "data"))
FIXTURES = REPO / "fixtures"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} not available")
    return SHARED_DATA


@pytest.fixture(scope="session")
def fixtures_dir() -> Path:
    """Path of the repository's fixtures/ folder."""
    return FIXTURES


def _torch_devices() -> list:
    try:
        import torch
    except ImportError:
        return [pytest.param("cpu", marks=pytest.mark.skip(reason="PyTorch is not installed (optional: "
                                                                  "pip install -e '.[torch]')"))]
    env = os.environ.get("POLCAM_TEST_DEVICES")
    if env:
        return [d for d in env.split(",") if d]
    return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=_torch_devices())
def dev(request: pytest.FixtureRequest) -> str:
    """A PyTorch device name to run the test on."""
    return request.param
