"""polcam.registry: the registry both method packages use (order, defaults, removal, plugins)."""

from __future__ import annotations

import sys

import pytest

from polcam.errors import MethodError
from polcam.registry import Registry


def test_names_follow_the_order_then_sort_and_unknown_names_list_them():
    reg: Registry[int] = Registry("toy method", order=("b", "a"), defaults={"stack": "a"})
    for name, value in (("z", 1), ("a", 2), ("c", 3), ("b", 4)):
        reg.add(name, value)
    assert reg.names() == ("b", "a", "c", "z") and len(reg) == 4 and "c" in reg
    assert reg.get("c") == 3 and reg.default("stack") == "a"
    with pytest.raises(MethodError, match=r"toy method 'y' is unknown; expected one of b, a, c, z"):
        reg.get("y")
    with pytest.raises(MethodError, match=r"input form 'image': expected one of stack"):
        reg.default("image")
    assert reg.remove("z") == 1 and "z" not in reg
    with pytest.raises(MethodError, match="'z' is unknown"):
        reg.remove("z")


def _plugin(site, name: str, group: str, body: str) -> None:
    (site / f"{name}.py").write_text(body)
    info = site / f"{name}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{group}]\n{name} = {name}\n")


def test_plugins_load_once_on_a_miss_and_a_broken_one_is_named(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    group = "polcam.test-registry-plugins"
    reg: Registry[str] = Registry("toy method", plugins=group)
    monkeypatch.setattr(sys.modules[__name__], "REG", reg, raising=False)
    _plugin(tmp_path, "toy_plugin_ok", group, f"import {__name__} as t\nt.REG.add('from-plugin', 'loaded')\n")
    reg.add("own", "here")
    assert reg.get("own") == "here" and "from-plugin" not in reg      # a known name loads nothing
    assert reg.get("from-plugin") == "loaded"                           # a miss loads the plugins
    assert reg.names() == ("from-plugin", "own")
    monkeypatch.delitem(sys.modules, "toy_plugin_ok")

    broken: Registry[str] = Registry("toy method", plugins=group + "-broken")
    _plugin(tmp_path, "toy_plugin_broken", group + "-broken", "raise RuntimeError('no GPU here')\n")
    with pytest.raises(MethodError, match=r"plugin 'toy_plugin_broken' \(toy_plugin_broken, entry point group "
                                          r".*-broken\) failed to load: RuntimeError: no GPU here"):
        broken.names()
    assert broken.names() == ()                                         # tried once; the error was reported
