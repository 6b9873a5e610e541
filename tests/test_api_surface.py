"""The public API: the exact public names of polcam's packages, each of which resolves.

A name removed or renamed fails here; a name added must be added here on purpose.
The registries' lists (polcam.METHODS, polcam.DEMOSAIC_METHODS) are read live.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

SURFACE: dict[str, set[str]] = {
    "polcam": {"DEMOSAIC_METHODS", "Frame", "Layout", "METHODS", "PolcamError", "Separation", "Stokes", "__version__", "aolp",
               "demosaic", "dolp", "imax", "imin", "parse_layout", "read_frame", "read_image", "separate", "stokes", "write_image"},
    "polcam.separation": {"METHODS", "SATURATED", "MethodSpec", "ResolvedSeparation", "Separation", "check_options",
                          "default_method", "estimated_illuminant", "input_form", "layout_form", "method_spec",
                          "methods", "register", "resolve_separation", "separate", "takes_illuminant",
                          "unregister"},
    "polcam.demosaicing": {"DEMOSAIC_METHODS", "RESOLUTIONS", "MethodSpec", "ResolvedDemosaic", "default_method",
                           "demosaic", "method_spec", "methods", "mosaic_stack", "register", "resolve_demosaic",
                           "to_float", "unregister"},
    "polcam.registry": {"Registry"},
    "polcam.io": {"IMAGE_EXTENSIONS", "RAW_EXTENSIONS", "atomic_path", "atomic_write", "pack", "packed_size",
                  "read_frame", "read_image", "read_sidecar", "sidecar_path", "unpack", "write_frame",
                  "write_image", "write_sidecar"},
    "polcam.camera": {"AravisCamera", "Camera", "CameraBusyError", "CameraDisconnectedError", "CameraNotFoundError",
                      "CameraSettingError", "CameraSettings",
                      "CapturedFrame", "DeviceInfo", "FrameTimeout", "ReplayCamera", "StreamStats",
                      "TRIGGER_MODES", "aravis_available", "as_recorded", "backends", "list_devices",
                      "load_aravis", "open_camera", "register_backend"},
    "polcam.calibration": {"Calibration", "CalibrationError", "FORMAT", "MAPS", "MIN_ANGLES", "VERSION",
                           "analysis_matrices", "apply_calibration", "calibrate_dark", "calibrate_flat",
                           "calibrate_polarizer", "check_angles", "correct_stack", "correction_matrices",
                           "diattenuation_to_extinction", "extinction_to_diattenuation", "fill_defects",
                           "forward", "load_calibration", "measurement_rows", "save_calibration"},
    "polcam.polarimetry": {"MAPS", "Sinusoid", "Stokes", "aolp", "dolp", "fit_residual", "fit_sinusoid", "imax",
                           "imin", "maps", "maps_from_stokes", "maps_together", "stokes", "synthesize"},
    "polcam.pipeline": {"FrameResult", "LiveMaps", "PRODUCTS", "calibrate", "default_demosaic", "live_maps", "products",
                        "require_layout", "run_frame", "separate_layers", "to_stack"},
    "polcam.sinks.files": {"FOLDER_PRODUCTS", "FORMATS", "ProductFiles", "check_format", "extension",
                           "file_record", "read_frame_folder", "write_meta", "write_products"},
    "polcam.sinks.base": {"FanOut", "Record", "Sink", "SinkBase"},
    "polcam.acquisition": {"Capture", "CaptureOptions", "Counters", "FrameSaver", "LiveProcessor", "SAVE_FORMATS",
                           "StopRequest", "frame_name", "run_capture", "write_captured_frame"},
    "polcam.mosaic": {"ANGLES", "BAYER_PATTERNS", "LAYOUTS", "Layout", "PIXEL_FORMATS", "PixelFormat",
                      "VENDOR_ALIASES", "parse_layout", "pixel_format", "supported_pixel_formats", "vendor_key"},
    "polcam.frame": {"Frame", "SIDECAR_KEYS"},
    "polcam.errors": {"CameraUnavailableError", "FrameReadError", "FrameWriteError", "LayoutError",
                      "MethodError", "PixelFormatError", "PolcamError"},
    "polcam.process": {"FrameJob", "OUTPUTS", "ProcessOptions", "check_run", "layout_hint", "plan", "process_frame",
                       "run", "sha256_file"},
}


@pytest.mark.parametrize("module", sorted(SURFACE))
def test_public_names_are_exactly_these(module):
    mod = importlib.import_module(module)
    assert set(mod.__all__) == SURFACE[module]
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f"{module}.__all__ names that do not resolve: {missing}"


def test_method_lists_follow_the_registries():
    import polcam
    from polcam.separation import methods, register, unregister

    assert polcam.METHODS == methods() and "tensor" in polcam.METHODS and "imin" in polcam.METHODS
    assert "bilinear" in polcam.DEMOSAIC_METHODS

    def halve(image):
        return np.asarray(image) * 0.5

    register("api-surface-probe", kind="single")(halve)
    try:
        assert "api-surface-probe" in polcam.METHODS
        assert "api-surface-probe" in importlib.import_module("polcam.separation").METHODS
    finally:
        unregister("api-surface-probe")
    assert "api-surface-probe" not in polcam.METHODS


def test_read_image_sits_beside_write_image(tmp_path):
    import polcam

    img = np.linspace(0, 1, 48, dtype=np.float32).reshape(4, 4, 3)
    polcam.write_image(tmp_path / "x.exr", img)
    back, _ = polcam.read_image(tmp_path / "x.exr")
    np.testing.assert_array_equal(back, img)


def test_unknown_attribute_is_an_attribute_error():
    import polcam

    with pytest.raises(AttributeError, match="no_such_name"):
        polcam.no_such_name  # noqa: B018


def test_pipeline_steps_are_functions_that_compose():
    """One kind of name for one kind of step: each public step is a function, and what one returns the
    next accepts (demosaic -> stokes -> dolp / aolp)."""
    import polcam

    for name in ("demosaic", "stokes", "dolp", "aolp", "imin", "imax", "separate"):
        assert callable(getattr(polcam, name)), name
    raw = np.random.default_rng(0).random((16, 16)).astype(np.float32)
    stack = polcam.demosaic(raw, layout="imx250mzr", method="bilinear")
    s = polcam.stokes(stack)
    assert isinstance(s, polcam.Stokes)
    assert polcam.dolp(s).shape == raw.shape and polcam.aolp(stack).shape == raw.shape
