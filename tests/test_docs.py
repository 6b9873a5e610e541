"""The defaults the docs state are the registries' defaults.

README.md and docs/guide/process.md each hold one marked statement, a paragraph starting "Defaults:",
naming the separation default for colour and mono stacks and the demosaicing default for colour
and mono layouts; it must name what `polcam.separation.default_method` and
`polcam.demosaicing.default_method` return. Flags documented with a default method must agree too.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

_NAME = r"`([a-z0-9-]+)`"
_STATEMENT = re.compile(
    rf"Defaults: separation {_NAME} for colour stacks, {_NAME} for mono stacks; "
    rf"demosaicing {_NAME} for colour, {_NAME} for mono\b")


def _text(rel: str) -> str:
    """The file's text with every run of white space (line breaks included) as one space."""
    return " ".join((REPO / rel).read_text().split())


def _registry() -> tuple[str, str, str, str]:
    from polcam.demosaicing import default_method as demosaic_default
    from polcam.separation import default_method

    return (default_method("stack"), default_method("mono-stack"), demosaic_default("imx250myr"),
            demosaic_default("imx250mzr"))


@pytest.mark.parametrize("doc", ["README.md", "docs/guide/process.md"])
def test_the_stated_defaults_are_the_registrys(doc):
    found = _STATEMENT.findall(_text(doc))
    assert len(found) == 1, f"{doc}: expected one 'Defaults: separation `A` for colour stacks, ...' statement"
    assert found[0] == _registry(), f"{doc} states {found[0]}, the registries say {_registry()}"


def test_the_statement_parser_catches_a_wrong_default():
    wrong = ("Defaults: separation `imin` for colour stacks, `polarized-residual` for mono stacks; "
             "demosaicing `lmmse` for colour, `eari` for mono.")
    (found,) = _STATEMENT.findall(wrong)
    assert found != _registry() and found[0] == "imin"


@pytest.mark.parametrize("doc", ["README.md", "docs/guide/process.md"])
def test_no_flag_is_documented_with_another_default_method(doc):
    # "`--separate imin` (default)" or "--method NAME (default `NAME`)": a default method named
    # beside a method flag must be one of the registries' defaults
    from polcam.demosaicing import DEMOSAIC_METHODS
    from polcam.separation import methods

    names = set(methods()) | set(DEMOSAIC_METHODS)
    text = _text(doc)
    claims = re.findall(r"--(?:separate|method|demosaic)[ =]`?([a-z0-9-]+)`? \(default\)", text)
    claims += re.findall(r"--(?:separate|method|demosaic) [A-Z|a-z]+`? \(default `([a-z0-9-]+)`\)", text)
    stated = [c for c in claims if c in names]
    assert all(c in _registry() for c in stated), (doc, stated, _registry())
