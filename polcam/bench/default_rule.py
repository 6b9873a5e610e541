"""The default-method rule (docs/benchmarks.md, "Default method rule") and the table it reads.

The registry's defaults (:func:`polcam.separation.default_method`, what
``polcam.separate``, ``polcam process``, ``polcam capture`` and the demo run
without a method) are chosen by a written rule from recorded figures:

Colour stacks:

1. **No harm on real frames**: over every relit variant of the real stacks
   (:data:`polcam.bench.relit.VARIANTS`), the matte achromatic pixels keep at
   least :data:`MATTE_KEPT_MEAN` of their light on the mean over the stacks
   and at least :data:`MATTE_KEPT_EACH` on each stack;
2. **no invented structure** in clipped regions: ``invented`` at most
   :data:`INVENTED_MAX` on every stack and variant (about the demosaicing's own
   variation inside a clipped region; ``imin``, which only reads the samples,
   scores 0.003);
3. **it separates**: on the real stacks it removes at least as much of the
   brightest 1 % (``top_removed``) as the reference baseline
   :data:`HIGHLIGHT_REFERENCE` and its specular layer's colour spread is no
   wider (the dichromatic model's one specular colour).  A method that
   removes only the polarized light (``imin``) keeps every surface but leaves
   the unpolarized part of each highlight in the diffuse and puts the
   polarized part of the diffuse light in the specular layer; this step keeps
   such a method from winning on harm alone.  Where the reference was not
   measured (mono) the step is skipped;
4. of the methods that pass, the best mean object PSNR of the diffuse on the
   randomized family's ``validation`` split;
5. if none passes, the highest matte achromatic kept (the lowest over
   variants of the mean over stacks) among the methods whose specular colour
   spread is at most :data:`SPREAD_FALLBACK`.

Mono stacks: the same, with the figures of the mono camera (the real stacks'
luminance through an IMX250MZR mosaic, the family's luminance truth); where
the table holds no real figures for a mono method, step 4 alone.

``polcam bench default-rule --real R [--real R2] [--real-mono RM] --validation V
--validation-mono M --out FILE`` assembles the table from the outputs of ``polcam bench real
--relit [--mono]`` (``R``, ``RM`` = their ``relit.json``) and ``polcam bench quality --set random --split validation
[--mono]`` (``V``, ``M`` = their ``scores.csv``), prints the choice and writes
``FILE`` (the recorded table is ``tests/separation/default_rule_table.json``; a
test checks the registry against it).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MATTE_KEPT_MEAN", "MATTE_KEPT_EACH", "INVENTED_MAX", "SPREAD_FALLBACK", "HIGHLIGHT_REFERENCE",
           "passes", "pick",
           "pick_all", "build_table"]

#: Least matte achromatic kept on the mean over the real stacks, in every variant.
MATTE_KEPT_MEAN = 0.90
#: Least matte achromatic kept on each real stack, in every variant.
MATTE_KEPT_EACH = 0.85
#: Most structure invented in clipped regions (share of the light there), on every stack and variant.
INVENTED_MAX = 0.01
#: Fallback: the most specular colour spread a method may have.
SPREAD_FALLBACK = 0.05
#: Step 3's reference: the baseline whose highlight removal and specular colour spread a default
#: must match (the polarization-chromaticity method of Wen et al. 2021).
HIGHLIGHT_REFERENCE = "wen21"


def passes(row: dict[str, Any], reference: dict[str, Any] | None = None) -> bool:
    """Whether a method's row passes steps 1-3 (no harm on real frames, nothing invented, separates).

    ``reference``: the row of :data:`HIGHLIGHT_REFERENCE` (None: step 3 is skipped).
    """
    if "matte_kept_min_mean" not in row:
        return True   # no real figures (a mono method without a mono real table): step 4 alone
    ok = (row["matte_kept_min_mean"] >= MATTE_KEPT_MEAN and row["matte_kept_min"] >= MATTE_KEPT_EACH
          and row["invented_max"] <= INVENTED_MAX)
    if ok and reference is not None and "top_removed" in reference:
        ok = row["top_removed"] >= reference["top_removed"] and row["spread"] <= reference["spread"]
    return bool(ok)


def pick(rows: dict[str, dict[str, Any]]) -> tuple[str, str]:
    """The method the rule picks from one form's rows (method -> figures), and why.

    Parameters
    ----------
    rows
        Per method: ``validation_psnr`` (mean object PSNR, dB) and, where measured on the real
        stacks, ``matte_kept_min_mean``, ``matte_kept_min``, ``invented_max``, ``spread``.

    Returns
    -------
    method : str
    reason : str
    """
    if not rows:
        raise ValueError("no methods in the rule table")
    ref = rows.get(HIGHLIGHT_REFERENCE)
    ok = [m for m, r in rows.items() if passes(r, ref) and np.isfinite(r.get("validation_psnr", np.nan))]
    if ok:
        best = max(ok, key=lambda m: rows[m]["validation_psnr"])
        return best, (f"passes the real checks ({', '.join(ok)} do) and has the best validation mean "
                      f"among them: {rows[best]['validation_psnr']:.2f} dB")
    narrow = [m for m, r in rows.items() if r.get("spread", np.inf) <= SPREAD_FALLBACK]
    if not narrow:
        raise ValueError(f"no method passes and none has a specular spread <= {SPREAD_FALLBACK}")
    best = max(narrow, key=lambda m: rows[m]["matte_kept_min_mean"])
    return best, (f"no method passes; of those with specular spread <= {SPREAD_FALLBACK} "
                  f"({', '.join(narrow)}) it keeps the most matte achromatic light: "
                  f"{rows[best]['matte_kept_min_mean']:.3f}")


def pick_all(table: dict[str, Any]) -> dict[str, str]:
    """``{"stack": method, "mono-stack": method}`` from a recorded table (:func:`build_table`)."""
    return {"stack": pick(table["colour"])[0], "mono-stack": pick(table["mono"])[0]}


def _validation_means(path: Path) -> dict[str, float]:
    with Path(path).open() as fh:
        rows = list(csv.DictReader(fh))
    by: dict[str, list[float]] = {}
    for r in rows:
        if r["error"]:
            by.setdefault(r["method"], []).append(float("nan"))
        else:
            by.setdefault(r["method"], []).append(float(r["psnr_mask"]))
    return {m: float(np.mean(v)) for m, v in by.items()}


def build_table(real: Sequence[Path], validation: Path, validation_mono: Path, *,
                real_mono: Sequence[Path] = (), commands: Sequence[str] = ()) -> dict[str, Any]:
    """Assemble the rule's table from the benches' outputs.

    Parameters
    ----------
    real
        ``relit.json`` files of ``polcam bench real --relit`` (colour methods; a method's
        figures come from one file).
    validation, validation_mono
        ``scores.csv`` of ``polcam bench quality --set random --split validation`` (and ``--mono``).
    real_mono
        ``relit.json`` files of ``polcam bench real --relit --mono`` (none: step 4 alone for mono).
    commands
        The commands that produced the inputs (recorded in the table).
    """
    def rows(real_paths: Sequence[Path], val: Path) -> dict[str, dict[str, Any]]:
        means = _validation_means(val)
        summ: dict[str, Any] = {}
        for path in real_paths:
            summ.update(json.loads(Path(path).read_text())["summary"])
        out: dict[str, dict[str, Any]] = {}
        for m in dict.fromkeys([*summ, *means]):
            if real_paths and m not in summ:
                continue   # not measured on the real stacks: not a candidate
            row: dict[str, Any] = {k: round(float(v), 4) for k, v in summ.get(m, {}).items()}
            row["validation_psnr"] = round(means.get(m, float("nan")), 3)
            out[m] = row
        for row in out.values():
            row["passes"] = passes(row, out.get(HIGHLIGHT_REFERENCE))
        return out

    table = {
        "rule": {"matte_kept_mean": MATTE_KEPT_MEAN, "matte_kept_each": MATTE_KEPT_EACH,
                 "invented_max": INVENTED_MAX, "spread_fallback": SPREAD_FALLBACK,
                 "highlight_reference": HIGHLIGHT_REFERENCE},
        "commands": list(commands),
        "colour": rows(real, validation),
        "mono": rows(real_mono, validation_mono),
    }
    table["picked"] = {"stack": pick(table["colour"]), "mono-stack": pick(table["mono"])}
    return table
